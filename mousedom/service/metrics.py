"""Prometheus metrics: what the daemon is doing, for a scraper (docs/metrics.md).

``prometheus-client`` (the ``metrics`` extra) makes the exposition text and its registry;
opt in with ``outputs: {metrics: {}}``, which listens on 127.0.0.1:9464 unless the config
says otherwise.  The registry is the daemon's own, not the library's global one, so two
daemons in one process (the tests) or a restart never collide.

Nothing here runs per report, and almost nothing per window: the figures are read when a
scrape asks for them (a custom collector), from what the daemon keeps anyway:

- the POSE count, the clients and the pose covariance, read from the daemon at the scrape;
- each mouse's rate, reports, drops, residual and state: the SOURCE messages, which the
  daemon makes once a second (``sources``), kept as one tuple replaced whole;
- the CPU time per window: two ``thread_time`` calls around the loop's window work and a
  bucket increment (``WindowCpu``), the only work on the loop's path.

The scrape is served on a thread of its own (the library's WSGI server), so a slow scraper
never holds the loop; what it reads is either a single attribute (an int, a tuple, the
tracker's covariance list, replaced whole at each window) or a copy, so it never sees the
loop's structures half changed in a way that matters.
"""

from __future__ import annotations

import ipaddress
import logging
import socket
import sys
import threading
from bisect import bisect_left
from collections.abc import Iterator
from time import thread_time
from typing import Any, NamedTuple, Protocol

from mousedom.config import MetricsConfig
from mousedom.errors import UserError
from mousedom.fusion import robust
from mousedom.fusion.posebatch import PoseRow
from mousedom.service.output import Output

log = logging.getLogger(__name__)

INSTALL_HINT = (
    "outputs.metrics needs prometheus-client, which is not installed: "
    "pip install 'mousedom[metrics]' (or: pip install prometheus-client)"
)
# Upper bounds of the CPU-per-window histogram, seconds: the Python path costs a few hundred
# microseconds a window, the compiled core tens (docs/performance.md); 50 ms is a stall.
CPU_BUCKETS = (25e-6, 50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3, 20e-3, 50e-3)
# The values of the state label: the fusion's states, and "gone" (the device is not open)
STATES = (*robust.STATES, "gone")
# How soon the server thread sees a stop (SIGTERM must end the daemon within a second)
POLL_S = 0.1
# Scrapers at once, and how long one may take to send its request: each connection holds a
# thread and a file descriptor, and 150 idle half-sent requests used up the daemon's
# descriptors (its socket's clients refused, a sensor's reopen would fail).  A Prometheus
# server scrapes with one connection; more are answered once these are done.
MAX_SCRAPERS = 8
REQUEST_TIMEOUT_S = 5.0


def require() -> None:
    """Raise the install hint when prometheus-client is missing (before any sensor opens)."""
    try:
        import prometheus_client  # noqa: F401
    except ImportError:
        raise UserError(INSTALL_HINT) from None


class Watched(Protocol):
    """What the collector reads of the daemon at a scrape."""

    @property
    def poses(self) -> int: ...  # POSE lines made so far

    @property
    def not_updated(self) -> int: ...  # of which held (no rank: no motion invented)

    @property
    def clients(self) -> int: ...  # clients connected to the socket

    @property
    def dropped_clients(self) -> int: ...  # clients dropped for not reading

    @property
    def tracker(self) -> Any: ...  # .pose_cov, a 3x3 over (x, y, theta)


class MouseFigures(NamedTuple):
    """One mouse's SOURCE figures, as the last SOURCE message said them."""

    name: str
    reports_per_s: float  # measured (the SOURCE message's "rate_hz" on the wire)
    reports: int
    dropped: int
    residual: float | None  # metres, RMS over the last second's windows
    state: str


class WindowCpu:
    """CPU seconds the loop's thread spends per window: reading the sensors, closing the
    windows, sending them.  A wake that closes no window (one mouse still owed) hands its
    time on to the next window; a wake that closes several shares its time among them."""

    __slots__ = ("counts", "sum", "_pending", "_t0", "_poses0")

    def __init__(self) -> None:
        self.counts = [0] * (len(CPU_BUCKETS) + 1)  # per bucket, not cumulative; last: +Inf
        self.sum = 0.0
        self._pending = 0.0
        self._t0 = 0.0
        self._poses0 = 0

    def start(self, poses: int) -> None:
        self._poses0 = poses
        self._t0 = thread_time()  # this thread only: a scrape's own work is not counted

    def stop(self, poses: int) -> None:
        spent = self._pending + (thread_time() - self._t0)
        windows = poses - self._poses0
        if windows <= 0:
            self._pending = spent
            return
        self._pending = 0.0
        self.counts[bisect_left(CPU_BUCKETS, spent / windows)] += windows
        self.sum += spent


def _mouse_figures(messages: list[dict[str, Any]]) -> tuple[MouseFigures, ...]:
    return tuple(
        MouseFigures(
            name=str(m["name"]),
            reports_per_s=float(m.get("rate_hz") or 0.0),
            reports=int(m.get("reports") or 0),
            dropped=int(m.get("dropped") or 0),
            residual=m.get("residual"),
            state=str(m.get("state") or "gone"),
        )
        for m in messages
    )


class DaemonCollector:
    """A prometheus-client collector that reads the daemon when scraped."""

    def __init__(self, daemon: Watched, cpu: WindowCpu) -> None:
        self.daemon = daemon
        self.cpu = cpu
        self.mice: tuple[MouseFigures, ...] = ()  # replaced whole by the loop's thread

    def collect(self) -> Iterator[Any]:
        from prometheus_client.core import (
            CounterMetricFamily,
            GaugeMetricFamily,
            HistogramMetricFamily,
        )

        d = self.daemon
        yield CounterMetricFamily(
            "mousedom_windows", "Windows closed and published as POSE lines", value=d.poses
        )
        yield CounterMetricFamily(
            "mousedom_windows_not_updated",
            "Windows whose pose was held: the live mice left the model without rank",
            value=d.not_updated,
        )
        yield GaugeMetricFamily(
            "mousedom_clients", "Clients connected to the Unix socket", value=d.clients
        )
        yield CounterMetricFamily(
            "mousedom_clients_dropped",
            "Clients dropped for not reading (their queue overflowed, or idle too long)",
            value=d.dropped_clients,
        )
        tracker = d.tracker
        if tracker is not None:
            cov = tracker.pose_cov
            # Separately: a trace over (x, y, theta) would add m^2 to rad^2.
            yield GaugeMetricFamily(
                "mousedom_pose_position_variance_square_meters",
                "Trace of the pose covariance's position block, var(x) + var(y)",
                value=float(cov[0][0] + cov[1][1]),
            )
            yield GaugeMetricFamily(
                "mousedom_pose_heading_variance_square_radians",
                "Variance of the heading, var(theta)",
                value=float(cov[2][2]),
            )
        yield from self._per_mouse()
        counts, total = list(self.cpu.counts), self.cpu.sum
        buckets, seen = [], 0
        for bound, n in zip((*CPU_BUCKETS, float("inf")), counts, strict=True):
            seen += n
            buckets.append(("+Inf" if bound == float("inf") else repr(bound), seen))
        h = HistogramMetricFamily(
            "mousedom_window_cpu_seconds",
            "CPU time of the daemon's loop per window: reading the sensors, fusing, sending",
        )
        h.add_metric([], buckets, sum_value=total)
        yield h

    def _per_mouse(self) -> Iterator[Any]:
        from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily

        mice = self.mice
        rate = GaugeMetricFamily(
            "mousedom_mouse_report_rate_hertz",
            "Reports a second from each mouse, over about the last second",
            labels=["mouse"],
        )
        reports = CounterMetricFamily(
            "mousedom_mouse_reports", "Reports read from each mouse", labels=["mouse"]
        )
        dropped = CounterMetricFamily(
            "mousedom_mouse_dropped_reports",
            "Reports each mouse lost before the daemon (SYN_DROPPED, serial gaps, CRC errors)",
            labels=["mouse"],
        )
        residual = GaugeMetricFamily(
            "mousedom_mouse_residual_meters",
            "RMS over the last second's windows of each mouse's rigidity residual",
            labels=["mouse"],
        )
        state = GaugeMetricFamily(
            "mousedom_mouse_state",
            "Each mouse's state: 1 for the current one, 0 for the others",
            labels=["mouse", "state"],
        )
        for m in mice:
            rate.add_metric([m.name], m.reports_per_s)
            reports.add_metric([m.name], m.reports)
            dropped.add_metric([m.name], m.dropped)
            if m.residual is not None:
                residual.add_metric([m.name], float(m.residual))
            for s in STATES:
                state.add_metric([m.name, s], 1.0 if s == m.state else 0.0)
        yield from (rate, reports, dropped, residual, state)


def _quiet_handler() -> type:
    """The WSGI request handler without a log line per scrape (stderr is the journal)."""
    from wsgiref.simple_server import WSGIRequestHandler

    class Handler(WSGIRequestHandler):
        timeout = REQUEST_TIMEOUT_S  # (StreamRequestHandler: the connection's socket timeout)

        def log_message(self, format: str, *args: Any) -> None:  # noqa: A002
            pass

    return Handler


class MetricsExporter(Output):
    """The registry, the collector and the HTTP server on its own thread."""

    def __init__(self, cfg: MetricsConfig, daemon: Watched) -> None:
        require()
        from wsgiref.simple_server import make_server

        from prometheus_client import CollectorRegistry, make_wsgi_app
        from prometheus_client.exposition import ThreadingWSGIServer
        from prometheus_client.process_collector import ProcessCollector

        self.cfg = cfg
        self.window_cpu = WindowCpu()
        self.collector = DaemonCollector(daemon, self.window_cpu)
        self.registry = CollectorRegistry()
        self.registry.register(self.collector)
        ProcessCollector(registry=self.registry)  # process_cpu_seconds_total, memory, fds

        family = socket.AF_INET
        if cfg.host != "localhost" and ipaddress.ip_address(cfg.host).version == 6:
            family = socket.AF_INET6

        # The library's start_http_server, but with a stop that does not wait its 0.5 s
        # poll: SIGTERM ends the daemon within a second.
        class Server(ThreadingWSGIServer):
            address_family = family
            slots = threading.BoundedSemaphore(MAX_SCRAPERS)

            def process_request(self, request: Any, client_address: Any) -> None:
                # Past MAX_SCRAPERS at once a connection is closed unanswered (its scraper
                # retries at its next interval), not given a thread and kept.
                if not self.slots.acquire(blocking=False):
                    self.shutdown_request(request)
                    return
                try:
                    super().process_request(request, client_address)
                except BaseException:
                    self.slots.release()
                    raise

            def handle_error(self, request: Any, client_address: Any) -> None:
                # A scraper that timed out (REQUEST_TIMEOUT_S) or went: no traceback on
                # stderr (the journal) for each, as socketserver prints by default.
                log.debug("metrics: connection from %s failed: %s", client_address,
                          sys.exc_info()[1])  # fmt: skip

            def process_request_thread(self, request: Any, client_address: Any) -> None:
                try:
                    super().process_request_thread(request, client_address)
                finally:
                    self.slots.release()

        try:
            self.httpd = make_server(
                cfg.host, cfg.port, make_wsgi_app(self.registry), Server, _quiet_handler()
            )
        except OSError as e:
            raise UserError(
                f"Prometheus metrics: cannot listen on {cfg.host}:{cfg.port}: "
                f"{e.strerror or e} (outputs.metrics)"
            ) from None
        self.port = self.httpd.server_port
        self.thread = threading.Thread(
            target=self.httpd.serve_forever,
            kwargs={"poll_interval": POLL_S},
            name="mousedom-metrics",
            daemon=True,
        )
        self.thread.start()
        host = f"[{cfg.host}]" if family == socket.AF_INET6 else cfg.host
        log.info("Prometheus metrics on http://%s:%d/metrics", host, self.port)

    def publish(self, row: PoseRow) -> None:
        pass  # the counters are read from the daemon at a scrape

    def sources(self, messages: list[dict[str, Any]], t: float) -> None:
        """The daemon's SOURCE messages (once a second): each mouse's figures."""
        self.collector.mice = _mouse_figures(messages)

    def close(self) -> None:
        httpd = getattr(self, "httpd", None)
        self.httpd = None  # type: ignore[assignment]  # closed: a second close does nothing
        if httpd is not None:
            httpd.shutdown()
            httpd.server_close()
            self.thread.join(1.0)
