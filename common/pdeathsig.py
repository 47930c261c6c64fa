"""Die with the supervisor: each child arms its own parent-death signal, after exec.

The supervisor never runs code between fork and exec (it has threads by
then: ZeroMQ's, and ``preexec_fn`` is unsafe after fork in a threaded
process).  Instead it puts two variables into a child's environment
(:func:`child_env`, called by ``supervisor/children.py``): its own pid and the signal
the child should get when it dies.  The child calls :func:`arm` first thing,
on its main thread (the kernel looks at the setting of a child's main thread):

- ``prctl(PR_SET_PDEATHSIG, sig)``: the kernel sends ``sig`` when the
  supervisor (the thread that forked the child: its main thread) exits,
  however it exits, SIGKILL included;
- then it compares its parent's pid with the supervisor's: if they differ,
  the supervisor died before the prctl took effect and the child was
  re-parented; :func:`arm` returns False and the child exits at once.

Who calls it: ``rosworker.main.main`` (SIGKILL: a ROS worker without its
supervisor has nobody to answer), and the gunicorn master through
``app/gunicorn_conf.py``'s ``on_starting`` hook (SIGTERM: it then stops its
HTTP workers, which notice their master is gone).  Without the variables (a
process started by hand or by a test) nothing is armed.  Linux only; on other
systems :func:`arm` only does the parent check.
"""

from __future__ import annotations

import ctypes
import os
import signal
import sys
from collections.abc import Mapping

ENV_PID = "SOVD_SUPERVISOR_PID"
ENV_SIGNAL = "SOVD_PARENT_DEATH_SIGNAL"
_PR_SET_PDEATHSIG = 1


def child_env(death_signal: int, supervisor_pid: int | None = None) -> dict[str, str]:
    """The variables a child needs to arm ``death_signal`` against this process."""
    pid = os.getpid() if supervisor_pid is None else supervisor_pid
    return {ENV_PID: str(pid), ENV_SIGNAL: str(int(death_signal))}


def arm(environ: Mapping[str, str] = os.environ) -> bool:
    """Arm the parent-death signal the supervisor asked for; False if the supervisor is gone."""
    try:
        supervisor = int(environ[ENV_PID])
        sig = signal.Signals(int(environ.get(ENV_SIGNAL, int(signal.SIGTERM))))
    except (KeyError, ValueError):
        return True  # not started by a supervisor: nothing to die with
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, int(sig), 0, 0, 0) != 0:
            err = ctypes.get_errno()
            raise OSError(err, f"prctl(PR_SET_PDEATHSIG): {os.strerror(err)}")
    return os.getppid() == supervisor


def gunicorn_on_starting(server) -> None:
    """gunicorn's ``on_starting`` hook (in the master, before it listens or forks workers)."""
    if not arm():
        print("sovd-gateway-http: the supervisor is gone; not starting", file=sys.stderr, flush=True)
        raise SystemExit(1)
