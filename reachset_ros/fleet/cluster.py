"""Running the per-bag tasks on Dask distributed (``--workers N`` / ``--scheduler ADDRESS``).

:class:`Fleet` is the client side of a fleet run: it starts a ``LocalCluster`` of ``N``
single-threaded worker processes (``--workers N``) or connects to an existing scheduler
(``--scheduler tcp://host:8786``), sends one task per bag (:mod:`reachset_ros.fleet.tasks`),
prints progress lines (bags done, messages read, rate) on stderr and returns the results in
bag order. Dask is imported only here, and this module only when one of the two options is
given: without them nothing changes.

What crosses the network: to each task the bag's path and the small specs (the plant, the
estimator, the Theorem-1 rows: tens of kilobytes for k* = 125); back, per joint, 2 (k*+1)
floats of extremes per output normal, a few counters and the read report (and for
``synthesize`` the bag's recorded references). The bags themselves are read by the workers:
with ``--scheduler`` every worker must see the bags at the paths given (a shared file system).
"""
from __future__ import annotations

import logging
import sys
import time
import uuid

from ..errors import ReachsetError

#: seconds between two progress lines (the last one is always printed)
PROGRESS_EVERY_S = 1.0


def _rate(n, seconds):
    return n / seconds if seconds > 0 else 0.0


class Fleet:
    """A Dask client for one command: ``with Fleet(workers=2) as f: f.map(fn, bags, ...)``.

    Parameters
    ----------
    workers : int, optional
        Start a ``LocalCluster`` with this many worker processes (one thread each; the sweep
        holds the GIL between kernel calls, so processes scale and threads would not).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) instead.
    progress : file, "stderr" or None
        Where progress lines go (default: the current ``sys.stderr``; None: silent).
    """

    def __init__(self, workers=None, scheduler=None, progress="stderr", timeout=30.0):
        if (workers is None) == (scheduler is None):
            raise ReachsetError("give one of --workers N and --scheduler ADDRESS")
        if workers is not None and workers < 1:
            raise ReachsetError(f"--workers must be >= 1, got {workers}")
        self.workers, self.scheduler, self.progress, self.timeout = workers, scheduler, progress, timeout
        self.client = self.cluster = None

    def __enter__(self):
        from dask.distributed import Client, LocalCluster
        try:
            if self.workers is not None:
                self.cluster = LocalCluster(n_workers=self.workers, threads_per_worker=1, processes=True,
                                            dashboard_address=":0", silence_logs=logging.ERROR)
                self.client = Client(self.cluster)
            else:
                self.client = Client(self.scheduler, timeout=self.timeout)
                self.client.wait_for_workers(1, timeout=self.timeout)
        except (OSError, TimeoutError, ValueError) as e:
            self.__exit__(None, None, None)
            where = f"--scheduler {self.scheduler}" if self.scheduler else f"--workers {self.workers}"
            raise ReachsetError(f"{where}: cannot start or reach the Dask cluster: {e}") from None
        return self

    def __exit__(self, *exc):
        for c in (self.client, self.cluster):
            if c is not None:
                try:
                    c.close()
                except Exception:        # closing a half-started cluster: nothing left to do
                    pass
        self.client = self.cluster = None
        return False

    @property
    def description(self):
        return (f"LocalCluster of {self.workers} worker processes" if self.workers is not None
                else f"Dask scheduler {self.scheduler}")

    def map(self, fn, bags, *args, what="read", **kw):
        """``[fn(bag, *args, **kw) for bag in bags]`` on the cluster, in bag order.

        The specs in ``args``/``kw`` are scattered once (broadcast to the workers), not sent
        with every task. A task's :class:`ReachsetError` is raised after the other tasks end,
        for the first failing bag in order (the bag a single process would have failed on).
        """
        from dask.distributed import as_completed
        client = self.client
        shared = client.scatter(list(args) + [kw], broadcast=True, hash=False) if (args or kw) else None
        arg_futs, kw_fut = (shared[:-1], shared[-1]) if shared else ([], None)
        run = uuid.uuid4().hex[:12]          # task keys unique per call: never a cached result of another call
        futures = [client.submit(_call, fn, b, kw_fut, *arg_futs, key=f"reachset-{what}-{run}-{i}", pure=False)
                   for i, b in enumerate(bags)]
        index = {f.key: i for i, f in enumerate(futures)}
        results, errors = [None] * len(bags), {}
        t0 = last = time.perf_counter()
        messages = done = 0
        for fut in as_completed(futures):
            i = index[fut.key]
            try:
                results[i] = fut.result()
                messages += int(getattr(results[i], "messages", 0))
            except ReachsetError as e:
                errors[i] = e
            except Exception as e:      # a worker died or the task failed outside the core's checks
                errors[i] = ReachsetError(f"{bags[i]}: the task failed on the cluster: {type(e).__name__}: {e}")
            done += 1
            now = time.perf_counter()
            if self.progress is not None and (now - last >= PROGRESS_EVERY_S or done == len(bags)):
                last = now
                read = (f", {messages:,} messages, {_rate(messages, now - t0):,.0f} messages/s" if messages else "")
                print(f"fleet {what}: {done}/{len(bags)} bags{read} ({self.description})",
                      file=sys.stderr if self.progress == "stderr" else self.progress, flush=True)
        if errors:
            raise errors[min(errors)]
        return results


def _call(fn, bag, kw, *args):
    return fn(bag, *args, **(kw or {}))
