"""The supervisor: main process of the service; owns lifecycle and health.

Lifecycle (``state``): ``starting`` → ``running`` → ``stopping`` → ``stopped``.

starting
    take ``<runtime_dir>/supervisor.lock`` (one gateway per runtime dir), check
    that the bind address is free, prepare the HTTP side's files
    (``common/runfiles.py``: an empty metrics directory for gunicorn's
    ``PROMETHEUS_MULTIPROC_DIR``, no stale rate-limit buckets), start the ROS worker (``sovd-rosworker``),
    wait until it answers ``ping`` (``WORKER_BOOT_TIMEOUT``), start gunicorn,
    wait until it answers HTTP on the bind address (``HTTP_BOOT_TIMEOUT``),
    then ``READY=1``.  Any child that dies here ends the service: a worker
    that cannot boot is not retried in a loop: exit 3 if the first ROS
    worker exits 2 or 3 (bad settings, another gateway's worker holds the
    runtime dir) or gunicorn cannot load the app.
running
    ping the ROS worker (``stats``, short deadline) about every second and send
    ``WATCHDOG=1`` only while it answers within ``watchdog_threshold`` and is
    not degraded.  A worker silent for ``watchdog_grace`` s (or degraded that
    long) is SIGKILLed; a dead worker is restarted with exponential backoff,
    at most ``restart_limit`` times within ``restart_window`` s, then the
    supervisor gives up (exit 1).  A restarted worker that exits 2 or 3
    (cannot boot: its lock still held by a dying predecessor, rclpy failing to
    start) is one more failure under that limit: its cause may pass, and exit
    3 would keep systemd from restarting the service.  gunicorn dying ends the
    service (exit 1; systemd's ``Restart=on-failure`` starts it again).
stopping
    on SIGTERM/SIGINT/SIGHUP (or any failure above): ``STOPPING=1``, SIGTERM
    gunicorn (in-flight requests get ``shutdown_grace`` s), then SIGTERM the ROS
    worker (it drains), SIGKILL whatever is left past its deadline, reap.  A
    second signal while stopping kills at once.

The fleet (issue 34, ``supervisor/fleet/``, ``docs/fleet.md``): with ``fleet_aggregate`` the
gateway is the fleet gateway and runs no ROS worker; its fleet link (``sovd-fleetlink``) takes the
ROS worker's place above (booted, pinged, watched, restarted, its ``ping``/``stats`` on its own
control socket).  With ``fleet_link`` a robot's fleet link is one more child (``supervisor/fleet/child.py``):
started once gunicorn answers, restarted with a backoff whenever it dies (never a reason to stop the
gateway), stopped first.

Signal handlers only record the signal; ``signal.set_wakeup_fd`` wakes the
main loop, which acts.  Each child runs in its own process group (Ctrl-C in a
terminal reaches only the supervisor, which stops them in order) with a
parent-death signal, so a supervisor killed outright does not leave them
behind; each child arms it itself after exec (``common/pdeathsig.py``), as no
code may run between fork and exec in a process with threads.

Before fork / after fork: ``Supervisor.__init__`` touches nothing
process-wide; :meth:`Supervisor.run` installs the signal handlers and starts
the children.
"""

from __future__ import annotations

import collections
import logging
import os
import select
import signal
import subprocess
import time

from common import runfiles
from common.process import PidfileHeld, lock_pidfile
from common.settings import RESTART_ENV, Config
from ipc import protocol
from ipc.client import RosWorkerClient
from ipc.errors import IpcError
from ipc.fleet import endpoint as fleet_endpoint

from .children import Child, bind_problem, gunicorn_argv, http_answers, rosworker_argv
from .fleet.child import LinkChild, fleetlink_argv
from .limits import raise_nofile
from .sdnotify import Notifier, child_env

log = logging.getLogger("sovd.supervisor")

STARTING, RUNNING, STOPPING, STOPPED = "starting", "running", "stopping", "stopped"

EXIT_OK = 0
EXIT_FAILURE = 1
EXIT_CANNOT_BOOT = 3
WORKER_CANNOT_BOOT_CODES = (2, 3)  # the ROS worker's "bad settings" / "cannot boot"
GUNICORN_BOOT_ERRORS = (3, 4)      # gunicorn's WORKER_BOOT_ERROR / APP_LOAD_ERROR

WORKER_BOOT_TIMEOUT = 60.0   # rclpy import and node creation; slow on a cold disk
HTTP_BOOT_TIMEOUT = 60.0
WORKER_STOP_TIMEOUT = 3.0    # the ROS worker drains and exits; then SIGKILL
KILL_WAIT = 2.0              # after SIGKILL, for the kernel to let us reap
HEALTH_INTERVAL = 1.0
BACKOFF_BASE = 0.25
BACKOFF_MAX = 5.0
STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
SUPERVISOR_LOCK = "supervisor.lock"


class Supervisor:
    def __init__(self, cfg: Config, notifier: Notifier | None = None):
        self.cfg = cfg
        self.notifier = notifier if notifier is not None else Notifier()
        self.state = STOPPED
        # The fleet gateway (issue 34, fleet_aggregate) runs no ROS worker: its fleet link takes the
        # worker's place here (booted, watched and restarted the same way; docs/fleet.md).  A robot's
        # fleet link (fleet_link) is a child of its own, started once HTTP answers (``self.link``).
        self.aggregating = bool(cfg.fleet_aggregate)
        self.what = "fleet link" if self.aggregating else "ROS worker"
        self.worker: Child | None = None
        self.http: Child | None = None
        self.link = LinkChild(cfg.runtime_dir, self._child_env) if cfg.fleet_link else None
        self.client = RosWorkerClient(fleet_endpoint(cfg.runtime_dir) if self.aggregating
                                      else protocol.endpoint(cfg.runtime_dir))
        self._signals: collections.deque[int] = collections.deque()
        self._wake_r = self._wake_w = -1
        self._old_handlers: dict[int, object] = {}
        self._lock_fh = None
        # ROS worker health
        self.worker_ready = False
        self._boot_deadline = 0.0
        self._last_answer = 0.0
        self._silent_reported = 0
        self._degraded_since: float | None = None
        self._next_health = 0.0
        self._restarts: collections.deque[float] = collections.deque()
        self._restart_at: float | None = None
        self._restart_attempt = 0
        self._worker_starts = 0
        self._metrics_dir: str | None = None
        # HTTP side
        self._http_deadline = 0.0
        self._next_watchdog = 0.0

    # ---- lifecycle predicates -----------------------------------------------------------
    def is_starting(self) -> bool:
        return self.state == STARTING

    def is_running(self) -> bool:
        return self.state == RUNNING

    @property
    def healthy(self) -> bool:
        """The ROS worker answers in time and is not degraded: the condition for WATCHDOG=1."""
        return (self.worker_ready and self.worker is not None and self.worker.alive()
                and time.monotonic() - self._last_answer <= self._threshold
                and self._degraded_since is None)

    @property
    def _threshold(self) -> float:
        return self.cfg.watchdog_threshold / 1000.0

    # ---- entry point ----------------------------------------------------------------------
    def run(self) -> int:
        self.state = STARTING
        raise_nofile()  # issue 23: one descriptor per SSE stream; the children inherit the limit
        self._install_signals()
        code = EXIT_FAILURE
        try:
            code = self._start()
            if code is None:
                code = self._loop()
        except Exception:
            log.exception("supervisor failed")
            code = EXIT_FAILURE
        finally:
            self._shutdown()
            self._restore_signals()
            self.client.close()
            self.notifier.close()
            if self._lock_fh is not None:
                self._lock_fh.close()
            self.state = STOPPED
        log.info("stopped (exit code %d)", code)
        return code

    # ---- signals: record only; the loop acts -----------------------------------------
    def _on_signal(self, signum: int, _frame) -> None:
        self._signals.append(signum)

    def _install_signals(self) -> None:
        self._wake_r, self._wake_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        signal.set_wakeup_fd(self._wake_w, warn_on_full_buffer=False)
        for sig in (*STOP_SIGNALS, signal.SIGCHLD):
            self._old_handlers[sig] = signal.signal(sig, self._on_signal)

    def _restore_signals(self) -> None:
        for sig, handler in self._old_handlers.items():
            signal.signal(sig, handler)
        signal.set_wakeup_fd(-1)
        for fd in (self._wake_r, self._wake_w):
            if fd >= 0:
                os.close(fd)
        self._wake_r = self._wake_w = -1

    def _wait_events(self, timeout: float) -> None:
        """Sleep until a signal arrives or ``timeout`` seconds pass."""
        if timeout > 0:
            try:
                select.select([self._wake_r], [], [], timeout)
            except InterruptedError:
                pass
        try:
            while os.read(self._wake_r, 512):
                pass
        except BlockingIOError:
            pass

    def _stop_requested(self) -> int | None:
        stop = None
        while self._signals:
            sig = self._signals.popleft()
            if sig in STOP_SIGNALS and stop is None:
                stop = sig
        return stop

    # ---- notify ---------------------------------------------------------------------------
    def _status(self, text: str, level: int = logging.INFO) -> None:
        log.log(level, "%s", text)
        self.notifier.status(text)

    # ---- starting -------------------------------------------------------------------------
    def _start(self) -> int | None:
        cfg = self.cfg
        try:
            self._lock_fh = lock_pidfile(os.path.join(cfg.runtime_dir, SUPERVISOR_LOCK))
        except PidfileHeld as exc:
            log.error("another sovd-gateway (pid %s) already runs with runtime dir %s; not starting",
                      exc.holder or "?", cfg.runtime_dir)
            return EXIT_CANNOT_BOOT
        problem = bind_problem(cfg.bind)
        if problem:
            log.error("cannot listen on %s: %s", cfg.bind, problem)
            return EXIT_FAILURE
        try:
            self._metrics_dir = runfiles.prepare(cfg.runtime_dir)
        except OSError as exc:
            log.error("cannot prepare %s: %s", runfiles.metrics_dir(cfg.runtime_dir), exc.strerror or exc)
            return EXIT_CANNOT_BOOT
        self._status(f"starting {self.what} (runtime dir {cfg.runtime_dir})")
        self._start_worker()
        return None

    def _child_env(self) -> dict[str, str]:
        env = child_env(os.environ)
        for key in ("SOVD_CONFIG", "LISTEN_FDS", "LISTEN_PID", "LISTEN_FDNAMES", "GUNICORN_FD",
                    runfiles.MULTIPROC_ENV):
            env.pop(key, None)
        env.update(self.cfg.to_env())
        env["PYTHONUNBUFFERED"] = "1"
        return env

    def _start_worker(self) -> None:
        self.client.close()  # a fresh socket for each worker
        env = self._child_env()
        if not self.is_starting():  # a restart: the worker may wait for its predecessor's lock
            env[RESTART_ENV] = str(self._restart_attempt)
        argv = fleetlink_argv(self.cfg.runtime_dir) if self.aggregating else rosworker_argv(self.cfg.runtime_dir)
        self.worker = Child(self.what, argv, env, signal.SIGKILL)
        self.worker.start()
        self.worker_ready = False
        self._degraded_since = None
        self._silent_reported = 0
        self._boot_deadline = time.monotonic() + WORKER_BOOT_TIMEOUT
        self._worker_starts += 1
        try:  # for the metrics: restarts, and when the running worker started
            runfiles.write_supervisor_state(self.cfg.runtime_dir, self._worker_starts - 1, time.time(),
                                            self.worker.pid)
        except OSError as exc:
            log.warning("cannot write %s: %s", runfiles.SUPERVISOR_STATE, exc.strerror or exc)
        log.info("%s pid %d started", self.what, self.worker.pid)

    def _start_http(self) -> None:
        env = self._child_env()
        if self._metrics_dir is not None:
            env[runfiles.MULTIPROC_ENV] = self._metrics_dir  # before gunicorn imports prometheus_client
        self.http = Child("gunicorn", gunicorn_argv(), env, signal.SIGTERM)
        self.http.start()
        self._http_deadline = time.monotonic() + HTTP_BOOT_TIMEOUT
        log.info("gunicorn pid %d started on %s", self.http.pid, self.cfg.bind)

    # ---- the loop -------------------------------------------------------------------------
    def _loop(self) -> int:
        while True:
            sig = self._stop_requested()
            if sig is not None:
                log.info("%s received: stopping", signal.Signals(sig).name)
                return EXIT_OK
            code = self._step()
            if code is not None:
                return code
            self._wait_events(self._next_wakeup() - time.monotonic())

    def _next_wakeup(self) -> float:
        now = time.monotonic()
        times = [now + HEALTH_INTERVAL]
        if self.is_starting() or (self.worker is not None and not self.worker_ready):
            times.append(now + 0.05)
        if self.worker_ready:
            times.append(self._next_health)
        if self._restart_at is not None:
            times.append(self._restart_at)
        if self.is_running() and self.notifier.watchdog_interval:
            times.append(self._next_watchdog)
        if self.link is not None and self.link.next_step is not None:
            times.append(self.link.next_step)
        return min(times)

    def _step(self) -> int | None:
        now = time.monotonic()
        if self.http is not None and not self.http.alive():
            return self._http_died()
        if self.worker is not None and not self.worker.alive():
            code = self._worker_died()
            if code is not None:
                return code
        if self.worker is None and self._restart_at is not None and now >= self._restart_at:
            self._restart_at = None
            self._status(f"restarting {self.what} (attempt {self._restart_attempt}/{self.cfg.restart_limit})")
            self._start_worker()
        if self.worker is not None and not self.worker_ready:
            code = self._check_boot(now)
            if code is not None:
                return code
        if self.is_starting() and self.http is not None:
            code = self._check_http(now)
            if code is not None:
                return code
        if self.worker_ready and now >= self._next_health:
            code = self._check_health()
            if code is not None:
                return code
        if self.link is not None:
            self.link.step(now)
        interval = self.notifier.watchdog_interval
        if self.is_running() and interval and now >= self._next_watchdog:
            if self.healthy:
                self.notifier.watchdog()
                self._next_watchdog = now + interval
            else:  # look again soon: ping as soon as the worker is healthy again
                self._next_watchdog = now + min(interval, self._health_interval)
        return None

    def _http_died(self) -> int:
        how = self.http.describe_exit()
        if self.is_starting() and self.http.returncode in GUNICORN_BOOT_ERRORS:
            self._status(f"gunicorn {how}: the HTTP app could not be loaded (see its log above)",
                         logging.ERROR)
            return EXIT_CANNOT_BOOT
        self._status(f"gunicorn pid {self.http.pid} {how} unexpectedly; stopping", logging.ERROR)
        return EXIT_FAILURE

    def _worker_died(self) -> int | None:
        worker, self.worker = self.worker, None
        was_ready, self.worker_ready = self.worker_ready, False
        how = worker.describe_exit()
        if worker.returncode in WORKER_CANNOT_BOOT_CODES:
            if self.is_starting():  # the first boot: retrying would not help
                self._status(f"{self.what} pid {worker.pid} {how}: it cannot boot "
                             f"(bad settings, or another {self.what} holds {self.cfg.runtime_dir}; "
                             "see its message above); not restarting it", logging.ERROR)
                return EXIT_CANNOT_BOOT
            return self._schedule_restart(f"{self.what} pid {worker.pid} {how}: the restarted worker "
                                          "could not boot (see its message above)")
        if self.is_starting():
            self._status(f"{self.what} pid {worker.pid} {how} before it was ready; not starting",
                         logging.ERROR)
            return EXIT_FAILURE
        what = "" if was_ready else " while booting"
        return self._schedule_restart(f"{self.what} pid {worker.pid} {how}{what}")

    def _schedule_restart(self, reason: str) -> int | None:
        now = time.monotonic()
        window, limit = self.cfg.restart_window, self.cfg.restart_limit
        while self._restarts and now - self._restarts[0] > window:
            self._restarts.popleft()
        if len(self._restarts) >= limit:
            self._status(f"{reason}; already restarted {len(self._restarts)} times within {window:g} s "
                         f"(restart_limit {limit}): giving up", logging.ERROR)
            return EXIT_FAILURE
        self._restarts.append(now)
        self._restart_attempt = len(self._restarts)
        delay = min(BACKOFF_MAX, BACKOFF_BASE * 2 ** (self._restart_attempt - 1))
        self._restart_at = now + delay
        self._status(f"{reason}; restarting it in {delay:g} s "
                     f"(attempt {self._restart_attempt}/{limit})", logging.WARNING)
        return None

    def _kill_worker(self, reason: str) -> int | None:
        worker = self.worker
        self._status(f"{reason}: killing {self.what} pid {worker.pid}", logging.ERROR)
        worker.kill_group()
        try:
            worker.proc.wait(KILL_WAIT)
        except subprocess.TimeoutExpired:
            log.error("%s pid %d did not die after SIGKILL", self.what, worker.pid)
        self.worker = None
        self.worker_ready = False
        return self._schedule_restart(f"{self.what} pid {worker.pid} killed")

    def _check_boot(self, now: float) -> int | None:
        worker = self.worker
        try:
            info = self.client.call("ping", timeout=0.3)
        except IpcError:
            info = None
        if info is not None and info.get("pid") == worker.pid:
            self.worker_ready = True
            self._last_answer = time.monotonic()
            self._next_health = self._last_answer + self._health_interval
            if self.is_starting():
                self._status(f"{self.what} pid {worker.pid} ready; starting gunicorn on {self.cfg.bind}")
                self._start_http()
            else:
                self._status(f"{self.what} pid {worker.pid} ready again; gunicorn listening on {self._url}")
            return None
        if info is not None:
            log.warning("another %s (pid %s) answers on %s; waiting for ours (pid %d)", self.what,
                        info.get("pid"), self.cfg.runtime_dir, worker.pid)
        if now >= self._boot_deadline:
            reason = f"{self.what} pid {worker.pid} did not answer ping within {WORKER_BOOT_TIMEOUT:g} s"
            if self.is_starting():
                self._status(reason + "; not starting", logging.ERROR)
                return EXIT_FAILURE
            return self._kill_worker(reason)
        return None

    @property
    def _url(self) -> str:
        return f"{'https' if self.cfg.tls_cert else 'http'}://{self.cfg.bind}"

    def _check_http(self, now: float) -> int | None:
        if http_answers(self.cfg.bind, tls=bool(self.cfg.tls_cert)):
            self.state = RUNNING
            text = f"{self.what} pid {self.worker.pid} ready; gunicorn listening on {self._url}"
            log.info("%s", text)
            self.notifier.ready(text)
            if self.link is not None:
                self.link.start()
            if self.notifier.watchdog_interval:
                self.notifier.watchdog()
                self._next_watchdog = now + self.notifier.watchdog_interval
            return None
        if now >= self._http_deadline:
            self._status(f"gunicorn did not answer HTTP on {self.cfg.bind} within "
                         f"{HTTP_BOOT_TIMEOUT:g} s; not starting", logging.ERROR)
            return EXIT_FAILURE
        return None

    @property
    def _health_interval(self) -> float:
        return max(0.1, min(HEALTH_INTERVAL, self._threshold / 2))

    def _check_health(self) -> int | None:
        """One ``stats`` round trip; acts on silence and on a degraded executor."""
        worker = self.worker
        timeout = max(0.05, min(0.5, self._threshold / 2))
        try:
            stats = self.client.call("stats", timeout=timeout)
        except IpcError:
            stats = None
        now = time.monotonic()
        self._next_health = now + self._health_interval
        grace = max(self.cfg.watchdog_grace, self._threshold)
        if stats is None:
            silent = now - self._last_answer
            if silent >= self._threshold and int(silent) != self._silent_reported:
                self._silent_reported = int(silent)
                self._status(f"{self.what} pid {worker.pid} not answering for {int(silent)} s",
                             logging.WARNING)
            if silent >= grace:
                return self._kill_worker(f"{self.what} pid {worker.pid} did not answer for {silent:.1f} s")
            return None
        recovered = self._silent_reported or self._degraded_since is not None
        self._last_answer = now
        self._silent_reported = 0
        if (stats.get("executor") or {}).get("degraded"):
            if self._degraded_since is None:
                self._degraded_since = now
                self._status(f"{self.what} pid {worker.pid} degraded: a ROS task runs longer than "
                             f"{self.cfg.watchdog_threshold} ms", logging.WARNING)
            elif now - self._degraded_since >= grace:
                return self._kill_worker(f"{self.what} pid {worker.pid} degraded for "
                                         f"{now - self._degraded_since:.1f} s")
            return None
        self._degraded_since = None
        if recovered:
            self._status(f"{self.what} pid {worker.pid} answering again; gunicorn listening on {self._url}")
        return None

    # ---- stopping -------------------------------------------------------------------------
    def _shutdown(self) -> None:
        if self.state == STOPPED:
            return
        self.state = STOPPING
        self.notifier.stopping(f"stopping: HTTP first, then the {self.what}")
        log.info("stopping")
        if self.link is not None:
            self.link.stop(self._stop_child)
        if self.http is not None:
            self._stop_child(self.http, signal.SIGTERM, self.cfg.shutdown_grace + 1.5)
        if self.worker is not None:
            self._stop_child(self.worker, signal.SIGTERM, WORKER_STOP_TIMEOUT)

    def _stop_child(self, child: Child, sig: int, timeout: float) -> None:
        if child.alive():
            log.info("stopping %s pid %d (%s, up to %g s)", child.name, child.pid,
                     signal.Signals(sig).name, timeout)
            child.send(sig)
            child.send(signal.SIGCONT)  # a stopped process cannot act on SIGTERM
            if not self._wait_exit(child, timeout):
                log.warning("%s pid %d still running: SIGKILL", child.name, child.pid)
        child.kill_group()  # the child if still there, and anything it left in its group
        try:
            child.proc.wait(KILL_WAIT)
        except subprocess.TimeoutExpired:
            log.error("%s pid %d could not be reaped", child.name, child.pid)
            return
        log.info("%s pid %d %s", child.name, child.pid, child.describe_exit())

    def _wait_exit(self, child: Child, timeout: float) -> bool:
        """Wait for ``child`` to exit; False past ``timeout`` or when a second stop signal came."""
        deadline = time.monotonic() + timeout
        while child.alive():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return False
            self._wait_events(min(remaining, 0.1))
            if self._stop_requested() is not None:
                log.warning("second stop signal: killing at once")
                return False
        return True
