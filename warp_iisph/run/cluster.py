"""Where the tasks of a sweep (or a render) run: one after another in this process, on a Dask
LocalCluster of worker processes started here, or on the cluster of any Dask scheduler (the
``cluster`` extra). A task runs alone in its worker process, with its share of the cores for
Warp's CPU launches, and may keep warm objects there for the tasks after it.

A LocalCluster has one thread per worker and gives each task ``cores // workers`` CPU threads; a
worker of another cluster runs one task at a time (each worker is given one of the Dask resource
``warp_iisph``, which every task asks for) with as many CPU threads as it has Dask threads
(``dask worker --nthreads``). With a GPU, tasks ask for the Dask resource ``GPU`` (one
task per GPU at a time): a LocalCluster's workers each hold one of this machine's GPUs, the
workers of another cluster must offer it (``dask worker --resources GPU=1``).
"""

from __future__ import annotations

import ctypes
import logging
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass

EXTRA = "pip install 'warp_iisph[cluster]'  (Dask distributed)"
MAX_WORKERS = 1024
CONNECT_TIMEOUT = "10s"
SLOT = "warp_iisph"  # the Dask resource of which each worker has one and each task takes one
PROFILER_CALLBACKS = ("profile", "profile-cycle")  # a Dask worker's periodic callbacks of its profiler
STOP_WAIT = 60.0  # seconds a stopped sweep waits for its running variants to record how they ended
# A LocalCluster's housekeeping, slowed: at Dask's intervals (a tick check every 20 ms, the system
# monitor every 0.5 s, the memory monitor every 0.1 s, in each process) an idle cluster of 2 took
# 6 % of a core from the tasks, with these 1.2 % (benchmarks/cluster.py). They watch for blocked
# event loops, feed the dashboard's charts and a worker's memory limit: none needs 20 ms.
LOCAL_CLUSTER_CONFIG = {
    "distributed.admin.tick.interval": "500ms",
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.worker.memory.monitor-interval": "1s",
}


class ClusterUnavailable(RuntimeError):
    """Dask is not installed; the message says what to install."""


def require_dask() -> None:
    try:
        import distributed  # noqa: F401
    except ImportError:
        raise ClusterUnavailable(f"Dask is not installed (the cluster extra): {EXTRA}") from None


def check_options(scheduler: str | None, workers: int | None) -> None:
    """``ValueError`` naming the option (both given, a worker count out of range, an empty
    address); ``ClusterUnavailable`` when either asks for Dask and it is not installed."""
    if scheduler is not None and workers is not None:
        raise ValueError("--scheduler and --workers: give one (a cluster's address, or a number of local workers)")
    if workers is not None and not 1 <= workers <= MAX_WORKERS:
        raise ValueError(f"--workers {workers}: must be in [1, {MAX_WORKERS}]")
    if scheduler is not None and not scheduler.strip():
        raise ValueError("--scheduler: must be a scheduler's address, e.g. tcp://10.0.0.5:8786")
    if scheduler is not None or workers is not None:
        require_dask()


# --- in a worker ---------------------------------------------------------------------------------

_one_task = threading.Lock()  # Warp's module loads and CPU thread pool are per process: one task at a time
_warm: dict = {}
_given_threads: list = [None]  # the CPU threads the running task was given


def warm(key, make):
    """The object ``make()`` returns, made once per process under ``key`` and kept for the tasks
    after it (a renderer with its scene set up, kernels loaded)."""
    if key not in _warm:
        _warm[key] = make()
    return _warm[key]


def _dask_worker():
    try:
        from distributed import get_worker

        return get_worker()
    except (ImportError, ValueError):  # not in a Dask worker
        return None


def in_worker() -> bool:
    """Whether this runs in a Dask worker."""
    return _dask_worker() is not None


def worker_name() -> str:
    """The Dask worker a task runs on (its address), or ``this process``."""
    worker = _dask_worker()
    return str(worker.address) if worker is not None else "this process"


def task_threads(threads: int | None) -> int | None:
    """CPU threads for a task: ``threads``, else its Dask worker's thread count, else ``None``
    (this process's own setting)."""
    if threads is not None:
        return threads
    worker = _dask_worker()
    return int(worker.state.nthreads) if worker is not None else None


def current_threads() -> int | None:
    """The CPU threads the task running in this worker was given (``None`` outside a task of a
    cluster: this process's own setting)."""
    return _given_threads[0]


def task_device(device: str) -> str:
    """The device a task runs on: ``cuda`` is its worker's GPU (a worker named by a number k
    takes GPU k modulo those it sees, as a LocalCluster's workers are; any other takes the first
    it sees, as one started with ``CUDA_VISIBLE_DEVICES`` set to its GPU does)."""
    if device != "cuda":
        return device
    worker = _dask_worker()
    name = getattr(worker, "name", None)
    if isinstance(name, int):
        import warp as wp

        return f"cuda:{name % max(1, wp.get_cuda_device_count())}"
    return "cuda:0"


def prepare_process(threads: int | None) -> None:
    """Warp started quietly in this process, with ``threads`` CPU threads for its launches
    (``None``: as it is)."""
    import warp as wp

    from ..engine.devices import init_warp
    from ..engine.launch import set_threads

    wp.config.log_level = wp.LOG_WARNING
    init_warp()
    if threads is not None:
        set_threads(threads)


@contextmanager
def stop_when_cancelled(poll: float = 0.5):
    """Inside a Dask task: Ctrl-C (``KeyboardInterrupt``) in this thread once the task is
    cancelled (its sweep was stopped, or the client that wanted it went away), so that a run
    ends as ``interrupted`` and says so, as it would at a terminal; elsewhere nothing. The stop
    comes at most once, and never after the block."""
    worker = _dask_worker()
    key = worker.get_current_task() if worker is not None else None
    if key is None:
        yield
        return
    me, lock, done, finished = threading.get_ident(), threading.Lock(), [False], threading.Event()

    def watch():
        while not finished.wait(poll):
            task = worker.state.tasks.get(key)
            if task is None or task.state not in ("executing", "long-running"):
                with lock:
                    if not done[0]:
                        ctypes.pythonapi.PyThreadState_SetAsyncExc(
                            ctypes.c_ulong(me), ctypes.py_object(KeyboardInterrupt)
                        )
                return

    threading.Thread(target=watch, name="warp_iisph-stop", daemon=True).start()
    try:
        yield
    finally:
        with lock:
            done[0] = True  # and a stop set but not yet raised is dropped
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(me), ctypes.c_void_p(0))
        finished.set()


def _busy() -> bool:
    """Whether this worker process runs one of our tasks now."""
    return _one_task.locked()


def _task(threads, warp, fn, args):
    with _one_task:
        _given_threads[0] = task_threads(threads)
        if warp:
            prepare_process(_given_threads[0])
        return fn(*args)


# --- in this process -----------------------------------------------------------------------------


@dataclass
class Workers:
    """Where tasks run: ``client`` is ``None`` for this process, one task after another."""

    client: object = None
    count: int = 1
    threads: int | None = None  # CPU threads per task (None: each worker's own share)
    address: str | None = None
    local: bool = False  # a LocalCluster started here
    gpus: int = 0  # workers holding a GPU

    @property
    def serial(self) -> bool:
        return self.client is None

    def describe(self) -> dict:
        """What a result file records of where its tasks ran."""
        if self.client is None:
            return {"where": "this process, one task after another", "threads": self.threads}
        return {
            "where": "LocalCluster" if self.local else "scheduler",
            "scheduler": self.address,
            "workers": self.count,
            "threads_per_task": self.threads,
            "gpus": self.gpus,
        }

    def run(
        self,
        calls: list,
        on_done,
        on_start=None,
        gpu: bool = False,
        name: str = "task",
        wait_on_stop: bool = False,
        warp: bool = True,
    ) -> None:
        """Run ``calls`` (function, args) and call ``on_done(index, result, error)`` as each ends
        (``error``: its exception, or its worker's loss; ``result`` is then ``None``). In this
        process the calls run in order, as this process is set up, ``on_start(index)`` before
        each, and an exception other than ``Exception`` (Ctrl-C) stops them; on a cluster they
        are submitted at once (asking for a ``GPU`` with ``gpu``), each worker's Warp set up for
        them (unless ``warp`` is false: tasks that launch no kernel), and what is left is
        cancelled when this returns or raises (then, with ``wait_on_stop``, the tasks running are
        given up to ``STOP_WAIT`` seconds to stop: those that use :func:`stop_when_cancelled`
        record how they ended)."""
        if self.client is None:
            for i, (fn, args) in enumerate(calls):
                if on_start is not None:
                    on_start(i)
                try:
                    with _one_task:
                        result = fn(*args)
                except Exception as e:  # noqa: BLE001 - handed to on_done, which decides
                    on_done(i, None, e)
                else:
                    on_done(i, result, None)
            return
        import uuid

        from distributed import as_completed

        tag = uuid.uuid4().hex[:8]
        futures = [
            self.client.submit(
                _task,
                self.threads,
                warp,
                fn,
                args,
                key=f"{name}-{i}-{tag}",
                pure=False,
                resources={SLOT: 1, "GPU": 1} if gpu else {SLOT: 1},
            )
            for i, (fn, args) in enumerate(calls)
        ]
        index = {f.key: i for i, f in enumerate(futures)}
        stopped = True
        try:
            for future in as_completed(futures):
                try:
                    result = future.result()
                except Exception as e:  # noqa: BLE001 - the task's error or the loss of its worker
                    on_done(index[future.key], None, e)
                else:
                    on_done(index[future.key], result, None)
            stopped = False
        finally:
            self.client.cancel(futures)
            if stopped and wait_on_stop:
                self._wait_idle(STOP_WAIT)

    def _wait_idle(self, timeout: float) -> None:
        """Wait until no worker runs one of our tasks (at most ``timeout`` seconds)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                if not any(self.client.run(_busy).values()):
                    return
            except Exception:  # noqa: BLE001 - a worker gone: nothing left to wait for there
                return
            time.sleep(0.25)


@contextmanager
def _children_ignore_sigint():
    """Processes started inside inherit SIGINT ignored: a Ctrl-C at the terminal (which the
    whole process group gets) reaches this process alone, which shuts the workers down in order.
    A Ctrl-C while they start is lost."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _local_gpus() -> int:
    import warp as wp

    from ..engine.devices import init_warp

    wp.config.log_level = wp.LOG_WARNING
    init_warp()
    return wp.get_cuda_device_count() if wp.is_cuda_available() else 0


@contextmanager
def open_workers(
    scheduler: str | None = None,
    workers: int | None = None,
    threads: int | None = None,
    gpu: bool = False,
):
    """The :class:`Workers` tasks run on: this process (neither ``scheduler`` nor ``workers``), a
    LocalCluster of ``workers`` processes started here and shut down on leaving (also on Ctrl-C),
    or the cluster whose scheduler is at ``scheduler``. ``threads``: CPU threads per task
    (default: the cores over the workers, for a LocalCluster). ``gpu``: the tasks run on GPUs,
    one per GPU (a LocalCluster has at most one worker per GPU of this machine)."""
    check_options(scheduler, workers)
    if scheduler is None and workers is None:
        yield Workers(threads=threads)
        return
    from distributed import Client, LocalCluster

    from ..engine.launch import available_cores

    cluster = client = None
    try:
        if workers is not None:
            extra = {}
            if gpu:
                gpus = _local_gpus()
                if gpus == 0:
                    raise ValueError("--device cuda: no CUDA device is available on this machine; use --device cpu")
                if workers > gpus:
                    print(f"warp-iisph: {gpus} workers, one per GPU of this machine (not {workers})", file=sys.stderr)
                    workers = gpus
                extra["resources"] = {"GPU": 1}
            threads = threads or max(1, available_cores() // workers)
            import dask

            # Dask's own errors are tracebacks on stderr (a worker's heartbeat that meets the
            # scheduler already closed, at every other Ctrl-C on a busy machine); a task's failure
            # and a worker's loss reach the caller through the task's future, said in one line.
            with _children_ignore_sigint(), dask.config.set(LOCAL_CLUSTER_CONFIG):
                cluster = LocalCluster(
                    n_workers=workers,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=":8787",
                    silence_logs=logging.CRITICAL,
                    **extra,
                )
            client = Client(cluster)
            _one_task_per_worker(client)
            _say_dashboard(client)
            pool = Workers(client, workers, threads, cluster.scheduler_address, local=True, gpus=workers if gpu else 0)
        else:
            try:
                client = Client(scheduler, timeout=CONNECT_TIMEOUT)
            except Exception as e:  # noqa: BLE001 - an unreachable or malformed address, in one line
                raise ValueError(f"--scheduler {scheduler}: cannot connect ({' '.join(str(e).split())})") from None
            info = client.scheduler_info()["workers"]
            gpus = sum(1 for w in info.values() if (w.get("resources") or {}).get("GPU"))
            if gpu and gpus == 0:
                raise ValueError(
                    f"--device cuda: no worker of the cluster at {scheduler} offers a GPU "
                    "(start them with: dask worker ADDRESS --resources GPU=1)"
                )
            pool = Workers(client, len(info), threads, scheduler, gpus=gpus)
        _one_task_per_worker(client)
        yield pool
    finally:
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()


def _one_task_per_worker(client) -> None:
    """Give every worker (those to come too) one ``SLOT``: Dask would hand a worker of n threads
    n tasks at once, of which all but one would wait for the process while other workers idle.
    And stop the worker's statistical profiler: it samples the task's thread every 10 ms, which
    cost a run 6-10 % of its wall time here (benchmarks/cluster.py) for a profile of kernel
    launches that says nothing."""
    from distributed import WorkerPlugin

    class OneTaskAtATime(WorkerPlugin):
        name = "warp_iisph-one-task-at-a-time"

        async def setup(self, worker):
            await worker.set_resources(**{SLOT: 1})
            for callback in PROFILER_CALLBACKS:
                sampler = worker.periodic_callbacks.pop(callback, None)
                if sampler is not None:
                    sampler.stop()

    client.register_plugin(OneTaskAtATime())


def _say_dashboard(client) -> None:
    try:
        import bokeh  # noqa: F401

        note = ""
    except ImportError:
        note = " (pip install bokeh to see it)"
    print(f"warp-iisph: Dask dashboard at {client.dashboard_link}{note}", file=sys.stderr)
