"""gunicorn settings for the HTTP side, read from the resolved ``SOVD_*`` settings.

The supervisor starts gunicorn as::

    python -m gunicorn -c python:app.gunicorn_conf 'app.wsgi:create_app()'

with every setting in the environment (``Config.to_env()``), so this module
holds no defaults of its own: it maps the gateway's settings onto gunicorn's.

- gevent workers (``app/http_worker.py``): each worker serves up to
  ``worker_connections`` connections on one event loop, a greenlet each, so
  idle, slow or streaming clients and requests waiting on the ROS worker hold
  no thread.  Every read from a client has a deadline there
  (``header_timeout``, ``body_timeout``, ``keepalive``).
- No ``preload_app``: the Flask app (and its ZeroMQ client) is made in each
  worker after the fork, never in the master.
- ``graceful_timeout`` is ``shutdown_grace``: on SIGTERM in-flight requests
  get that long, then gunicorn kills its workers.
- ``timeout`` (the worker heartbeat) is well above the longest request a
  worker may legitimately serve (a cold sample plus IPC).
- ``keepalive`` is longer than nginx's upstream ``keepalive_timeout`` (60 s),
  so gunicorn never closes an idle connection that nginx is about to reuse.
- Proxy headers (``X-Forwarded-*``) are trusted only from ``forwarded_allow_ips``.
- The access log is off unless ``access_log`` is set; then its lines are
  rate-limited by :class:`app.core.accesslog.AccessLogger` and carry the request id.
- TLS: ``tls_cert`` and ``tls_key`` are gunicorn's ``certfile`` and ``keyfile``; :func:`ssl_context`
  refuses anything older than ``tls_min_version`` (TLS 1.2 by default).
- Prometheus: the supervisor sets ``PROMETHEUS_MULTIPROC_DIR`` for gunicorn
  (``app/core/metrics.py``); when a worker exits, :func:`child_exit` marks its
  metric files dead, as prometheus_client's multiprocess mode prescribes.
"""

from __future__ import annotations

import math
import os

from common import settings as _config

_cfg = _config.load(None)

bind = [_cfg.bind]
workers = _cfg.workers
worker_class = "app.http_worker.HttpWorker"
worker_connections = _cfg.worker_connections
graceful_timeout = max(1, math.ceil(_cfg.shutdown_grace))  # gunicorn wants whole seconds
timeout = int(max(30.0, 2 * _cfg.sample_timeout + 2 * _cfg.ipc_timeout + 10))
keepalive = 75
forwarded_allow_ips = _cfg.forwarded_allow_ips
preload_app = False
# Heartbeat files of the workers: on the runtime dir (tmpfs under systemd, writable
# under ProtectSystem=strict) instead of the temp dir.
worker_tmp_dir = _cfg.runtime_dir if os.path.isdir(_cfg.runtime_dir) else None
# gunicorn >= 25 opens a control socket under $XDG_RUNTIME_DIR or $HOME by default:
# not wanted (ProtectHome=, several gateways per user in tests); gunicorn < 25 ignores this.
control_socket_disable = True
proc_name = "sovd-gateway-http"

loglevel = _cfg.log_level
errorlog = "-"
# Access lines on stdout (the journal) only when asked for, and then at a bounded rate.
logger_class = "app.core.accesslog.AccessLogger"
accesslog = "-" if _cfg.access_log else None
access_log_format = '%(h)s "%(r)s" %(s)s %(B)s %(M)sms request=%({x-request-id}o)s'


# TLS (issue 31): gunicorn's own certfile and keyfile, TLS 1.2 at least (tls_min_version); a
# plain-HTTP client gets no answer (its request is not a TLS handshake).  Empty: plain HTTP.
certfile = _cfg.tls_cert or None
keyfile = _cfg.tls_key or None


def ssl_context(config, default_ssl_context_factory):
    import ssl

    context = default_ssl_context_factory()
    context.minimum_version = ssl.TLSVersion.TLSv1_3 if _cfg.tls_min_version == "1.3" else ssl.TLSVersion.TLSv1_2
    return context


# Request limits: the body limit itself is enforced by the app (413); these bound headers.
limit_request_line = 8190
limit_request_fields = 100


def child_exit(server, worker):
    """In the master, after a worker exited: its live gauges leave the Prometheus sums."""
    if os.environ.get("PROMETHEUS_MULTIPROC_DIR"):
        from prometheus_client import multiprocess

        multiprocess.mark_process_dead(worker.pid)


# The master arms its own parent-death signal (SIGTERM) against the supervisor: common/pdeathsig.py.
from common.pdeathsig import gunicorn_on_starting as on_starting  # noqa: E402,F401 - a gunicorn hook
