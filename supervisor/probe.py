"""``sovd-probe``: ask the ROS worker directly, over its IPC socket.

    sovd-probe [--runtime-dir DIR | --endpoint URL] [--timeout S] [--json] COMMAND
      ping | stats | graph | sample TOPIC | evict TOPIC
      | watch TOPIC [--interval fast|normal|slow] [--bytes array|base64] [--count N] [--duration S]
      | faults [--all]

``watch`` prints the frames the ROS worker publishes for TOPIC on its events
channel (what cyclic-subscription streams are made of), one per line, until
Ctrl-C, ``--count`` frames or ``--duration`` seconds; it makes a subscription
of its own for that time (under the pseudo-app ``sovd-probe``) and deletes it
on the way out.

Human-readable output by default, one JSON document with ``--json``.
Exit codes (for scripts and container health checks)::

    0  the ROS worker answered
    1  it answered with an error (e.g. invalid topic)
    2  usage error
    3  no answer in time, or no ROS worker on that socket

``stats`` also exits 1 when the worker reports itself degraded and
``--fail-degraded`` is given, so a health check can act on it.
The default runtime dir is ``$SOVD_RUNTIME_DIR``, else the gateway's default
(``$RUNTIME_DIRECTORY``, else a private dir under ``$XDG_RUNTIME_DIR`` or /tmp).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import Any

from ipc import events, protocol
from ipc.client import RosWorkerClient
from ipc.errors import IpcError

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_UNAVAILABLE = 0, 1, 2, 3
NO_ANSWER = ("unavailable", "deadline-exceeded")


def _common(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """Options accepted before and after the command (``sovd-probe ping --json``)."""
    d = (lambda v: argparse.SUPPRESS) if suppress else (lambda v: v)
    parser.add_argument("--json", action="store_true", default=d(False), help="print one JSON document")
    parser.add_argument("--timeout", type=float, default=d(2.0), metavar="S",
                        help="seconds to wait for the answer (default 2)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sovd-probe", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="exit codes: 0 ok, 1 error reply, 2 usage, 3 no answer / unavailable")
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--runtime-dir", metavar="DIR", help="the gateway's runtime directory")
    where.add_argument("--endpoint", metavar="URL", help="ZeroMQ endpoint, e.g. ipc:///run/sovd-gateway/rosworker.sock")
    _common(parser, suppress=False)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, text in (("ping", "is the ROS worker there?"), ("stats", "its counters"),
                       ("graph", "the ROS graph as it sees it")):
        p = sub.add_parser(name, help=text)
        _common(p, suppress=True)
        if name == "stats":
            p.add_argument("--fail-degraded", action="store_true", help="exit 1 when the worker is degraded")
    for name, text in (("sample", "read one sample of TOPIC"), ("evict", "drop TOPIC from the pool"),
                       ("watch", "print TOPIC's frames from the events channel as they come")):
        p = sub.add_parser(name, help=text)
        p.add_argument("topic", metavar="TOPIC")
        _common(p, suppress=True)
        if name == "watch":
            p.add_argument("--interval", choices=tuple(events.INTERVALS), default="normal")
            p.add_argument("--bytes", choices=("array", "base64"), default="array", dest="bytes_mode")
            p.add_argument("--count", type=int, default=0, metavar="N", help="stop after N frames")
            p.add_argument("--duration", type=int, default=600, metavar="S",
                           help="stop after S seconds (default 600; at most max_stream_duration)")
    # faults (rosworker/faults/manager.py): the active faults, or every fault kept
    p = sub.add_parser("faults", help="the active faults (--all: also healed and cleared ones)")
    p.add_argument("--all", action="store_true", dest="all_faults", help="every fault the store keeps")
    _common(p, suppress=True)
    return parser


def default_endpoint(environ=os.environ) -> str:
    from common.settings import default_runtime_dir

    return protocol.endpoint(environ.get("SOVD_RUNTIME_DIR") or default_runtime_dir(environ))


def _request(args: argparse.Namespace) -> tuple[str, dict[str, Any], float]:
    timeout = args.timeout
    if args.command == "sample":
        # Leave the reply time to travel back before our own deadline.
        return "sample", {"topic": args.topic, "timeout_ms": max(1, int((timeout - 0.2) * 1000))}, timeout
    if args.command == "evict":
        return "evict", {"topic": args.topic}, timeout
    if args.command == "faults":  # faults: fault_list, the active ones unless --all
        statuses = ["PREFAILED", "CONFIRMED", "PREPASSED"] + (["HEALED", "CLEARED"] if args.all_faults else [])
        return "fault_list", {"statuses": statuses}, timeout
    return args.command, {}, timeout


def _jsonable(result: dict[str, Any]) -> dict[str, Any]:
    out = dict(result)
    raw = out.pop("data_json", None)
    if raw is not None:
        try:
            out["data"] = json.loads(raw)
        except (TypeError, ValueError):
            out["data"] = None
    return {k: (v.decode("utf-8", "replace") if isinstance(v, bytes) else v) for k, v in out.items()}


def _human(cmd: str, r: dict[str, Any]) -> str:
    if cmd == "ping":
        return (f"ROS worker pid {r.get('pid')} answers: node {r.get('node')}, "
                f"up {float(r.get('uptime_s', 0)):.1f} s, version {r.get('version')}, "
                f"protocol {r.get('protocol')}")
    if cmd == "stats":
        lines = [f"ROS worker pid {r.get('pid')}"]
        for section in ("data_provider", "executor"):
            lines.append(f"{section}:")
            lines += [f"  {k}: {json.dumps(v)}" for k, v in (r.get(section) or {}).items()]
        return "\n".join(lines)
    if cmd == "graph":
        lines = [f"generation {r.get('generation')}", "nodes:"]
        for n in r.get("nodes", []):
            lines.append(f"  {n.get('fqn')}  (publishes {len(n.get('publishes', []))}, "
                         f"subscribes {len(n.get('subscribes', []))})")
        lines.append("topics:")
        for t in r.get("topics", []):
            lines.append(f"  {t.get('name')}  {','.join(t.get('types', []))}  "
                         f"pub {t.get('publisher_count')} sub {t.get('subscriber_count')}")
        return "\n".join(lines)
    if cmd == "sample":
        head = f"{r.get('topic')} [{r.get('type')}] {r.get('status')}"
        if r.get("reason"):
            head += f" ({r['reason']})"
        head += f", publishers {r.get('publisher_count')}, timestamp {r.get('timestamp')}"
        return head + "\n" + json.dumps(r.get("data"), indent=2, ensure_ascii=False)
    if cmd == "evict":
        return f"{r.get('topic')}: " + ("evicted" if r.get("evicted") else "was not pooled")
    if cmd == "fault_list":  # faults
        items = r.get("items") or []
        if not items:
            return "no faults"
        return "\n".join(f"{f.get('fault_code')}  {f.get('status')}  {f.get('severity_label')}  "
                         f"x{f.get('occurrence_count')}  {','.join(f.get('reporting_sources') or [])}  "
                         f"{f.get('description')}" for f in items)
    return json.dumps(r, indent=2)


def main(argv: list[str] | None = None) -> int:
    """Run one command; a reader that goes away (``sovd-probe graph | head``) ends it quietly."""
    try:
        code = _run(argv)
        sys.stdout.flush()  # here, not at exit: a closed pipe is then caught below
        return code
    except BrokenPipeError:
        # The output was read as far as the reader wanted (a ``watch`` deletes its subscription
        # on the way out).  Nothing more is written: stdout goes to /dev/null, so Python's own
        # flush at exit does not print a traceback either.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
        return EXIT_OK


def _run(argv: list[str] | None) -> int:
    args = build_parser().parse_args(argv)  # exits 2 on usage errors
    if not (0 < args.timeout <= 600):
        print("sovd-probe: --timeout must be between 0 and 600 seconds", file=sys.stderr)
        return EXIT_USAGE
    if args.endpoint:
        endpoint = args.endpoint
    elif args.runtime_dir:
        endpoint = protocol.endpoint(args.runtime_dir)
    else:
        endpoint = default_endpoint()
    cmd, cmd_args, timeout = _request(args)

    if endpoint.startswith("ipc://") and not os.path.exists(endpoint[len("ipc://"):]):
        return _fail(args, "unavailable", f"no ROS worker socket at {endpoint[len('ipc://'):]} "
                     "(is the gateway running with this runtime dir, and may you enter it?)")
    client = RosWorkerClient(endpoint)
    if cmd == "watch":
        try:
            return _watch(args, client, endpoint)
        finally:
            client.close()
    try:
        result = client.call(cmd, cmd_args, timeout=timeout)
    except IpcError as exc:
        return _fail(args, exc.code, exc.message, exc.params)
    finally:
        client.close()
    out = _jsonable(result)
    if args.json:
        print(json.dumps({"ok": True, "command": cmd, "result": out}, ensure_ascii=False))
    else:
        print(_human(cmd, out))
    if cmd == "stats" and getattr(args, "fail_degraded", False) and (out.get("executor") or {}).get("degraded"):
        if not args.json:
            print("sovd-probe: the ROS worker is degraded", file=sys.stderr)
        return EXIT_ERROR
    return EXIT_OK


WATCHER = "sovd-probe"  # a pseudo-app: never the id of a real one (node names have no "-")


def _watch(args: argparse.Namespace, client: RosWorkerClient, endpoint: str) -> int:
    import signal
    import time

    import zmq

    from ipc.topics import InvalidTopic, normalize_topic

    try:
        topic = normalize_topic(args.topic)
    except InvalidTopic as exc:
        return _fail(args, "invalid-topic", str(exc))
    if args.count < 0 or args.duration <= 0:
        print("sovd-probe: --count must be >= 0 and --duration > 0", file=sys.stderr)
        return EXIT_USAGE
    try:
        sub = client.call("sub_create", {
            "collection": "apps", "entity_id": WATCHER, "resource": f"/api/v1/apps/{WATCHER}/data{topic}",
            "topic": topic, "bytes": args.bytes_mode, "interval": args.interval, "duration": args.duration,
        }, timeout=args.timeout)
    except IpcError as exc:
        return _fail(args, exc.code, exc.message, exc.params)
    stop = []
    old = signal.signal(signal.SIGINT, lambda *_: stop.append(True))
    ctx = zmq.Context()
    sock = ctx.socket(zmq.SUB)
    sock.setsockopt(zmq.LINGER, 0)
    for key in (sub["key"], events.CONTROL_KEY + sub["id"].encode()):
        sock.setsockopt(zmq.SUBSCRIBE, key)
    sock.connect(events.endpoint_beside(endpoint))
    shown = 0
    until = time.monotonic() + args.duration
    try:
        while not stop and time.monotonic() < until and (not args.count or shown < args.count):
            if not sock.poll(200):
                continue
            frames = sock.recv_multipart()
            if len(frames) < 2:
                continue  # the ROS worker's confirmation of a subscription (ipc/events.py)
            meta = protocol.unpack(frames[1])
            if frames[0] != sub["key"]:  # a control event: the subscription is gone
                if meta.get("event") in ("deleted", "expired"):
                    break
                continue
            shown += 1
            _print_frame(args, topic, meta, frames[2] if len(frames) > 2 else b"{}")
    finally:
        signal.signal(signal.SIGINT, old)
        sock.close()
        ctx.term()
        try:
            client.call("sub_delete", {"collection": "apps", "entity_id": WATCHER, "id": sub["id"]},
                        timeout=args.timeout)
        except IpcError:
            pass  # gone already (expired, or the worker restarted without it)
    return EXIT_OK


def _print_frame(args: argparse.Namespace, topic: str, meta: dict[str, Any], data: bytes) -> None:
    from datetime import UTC, datetime

    stamp = datetime.fromtimestamp(meta.get("ts", 0) / 1e9, UTC).strftime("%H:%M:%S.%f")[:-3]
    if args.json:
        out = {k: v for k, v in meta.items()}
        if "error" not in meta:
            out["data"] = json.loads(data)
        print(json.dumps(out, ensure_ascii=False), flush=True)
    elif "error" in meta:
        print(f"{stamp} {topic} error: {meta['error'].get('message')} [{meta['error'].get('code')}]", flush=True)
    else:
        what = meta.get("status")
        if meta.get("reason"):
            what += f" ({meta['reason']})"
        print(f"{stamp} {topic} [{meta.get('type')}] {what}: {data.decode('utf-8', 'replace')[:2000]}",
              flush=True)


def _fail(args: argparse.Namespace, code: str, message: str, params: dict | None = None) -> int:
    exit_code = EXIT_UNAVAILABLE if code in NO_ANSWER else EXIT_ERROR
    if args.json:
        print(json.dumps({"ok": False, "command": args.command,
                          "error": {"code": code, "message": message, "params": params or {}}}))
    else:
        print(f"sovd-probe: {args.command}: {message} [{code}]", file=sys.stderr)
    return exit_code


if __name__ == "__main__":
    sys.exit(main())
