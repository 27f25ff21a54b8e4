"""Fleet map/reduce on Dask: one task per log, one estimation per sensor (and period).

The steps are the use cases of ``app.fleet``: the map (``collect_log``) reads one log as
``calibrate`` reads it and returns its windows and pose changes (kilobytes; samples never
travel); the reduce (``reduce_unit``) runs the caller's ``reduce_fn(collected_list, paths)
-> CalibrationResult`` once per sensor (and ``period``) on a worker, with the map results
passed as futures (they move worker to worker, not through the client). ``cli.fleet``
passes ``app.fleet.calibrate_unit``: the very estimation of ``calibrate``. This module
only starts the cluster, submits the steps and gathers them.

A worker that dies mid-job loses its results; the scheduler recomputes them from the
task graph (``distributed.scheduler.allowed-failures`` retries), so nothing is lost.
"""

from contextlib import contextmanager
import os
import sys

from ..app.fleet import collect_log, header, period_key, reduce_unit


class FleetSetupError(ValueError):
    """A worker count, scheduler address or cluster that cannot be used; one line."""


#: seconds to reach a --scheduler and hear it answer as a Dask scheduler
CONNECT_TIMEOUT_S = 10.0
#: most LocalCluster worker processes accepted (per core: more only contend)
MAX_WORKERS_PER_CORE = 8


def check_workers(workers):
    """Refuse a LocalCluster worker count that is not 1..8 per core (None: one per core)."""
    if workers is None:
        return
    top = MAX_WORKERS_PER_CORE * (os.cpu_count() or 1)
    if not 1 <= workers <= top:
        raise FleetSetupError(f'--workers {workers}: give 1..{top} worker processes (this '
                              f'machine has {os.cpu_count() or 1} cores; default: one per core)')


def check_scheduler(address, timeout_s=CONNECT_TIMEOUT_S):
    """Refuse a --scheduler that is not a Dask scheduler answering within ``timeout_s``.

    One handshake and an ``identity`` request, bounded by ``timeout_s`` as a whole (an
    HTTP port that never answers, or one whose answer reads as a huge frame, is refused in
    one line, never a hang or a traceback).
    """
    import asyncio
    from distributed.comm import connect
    from distributed.comm.addressing import parse_address
    try:
        parse_address(address)
    except (ValueError, TypeError) as e:
        raise FleetSetupError(f'--scheduler {address!r}: not an address ({e}); give the '
                              'scheduler\'s address, e.g. tcp://host:8786') from None

    async def probe():
        comm = await connect(address, timeout=timeout_s)
        try:
            await comm.write({'op': 'identity', 'reply': True})
            return await comm.read()
        finally:
            comm.abort()
    what = None
    try:
        reply = asyncio.run(asyncio.wait_for(probe(), timeout_s))
    except (KeyboardInterrupt, SystemExit):
        raise
    except asyncio.TimeoutError:
        what = f'nothing answered as a Dask scheduler within {timeout_s:g} s'
    except BaseException as e:   # noqa: B902 - OSError, comm errors, MemoryError of garbage
        what = f'{type(e).__name__}: {str(e).splitlines()[0][:200] if str(e) else "failed"}'
    else:
        if not (isinstance(reply, dict) and reply.get('type') == 'Scheduler'):
            what = 'it answered, but not as a Dask scheduler'
    if what:
        raise FleetSetupError(f'--scheduler {address}: cannot use it ({what}); give the address '
                              'of a running Dask scheduler (dask scheduler prints it, e.g. '
                              'tcp://host:8786), or leave --scheduler out for a local cluster')


@contextmanager
def fleet_client(scheduler=None, workers=None, out=None):
    """Yield a ``distributed.Client``: on ``scheduler`` (an address) or a new LocalCluster.

    The LocalCluster has ``workers`` single-threaded worker processes (default: one per
    core) and its dashboard on a free port; the dashboard address is printed to ``out``.
    Both are checked first (``check_workers``, ``check_scheduler``: FleetSetupError, one
    line). The worker processes ignore SIGINT: Ctrl-C reaches this process only, which
    closes the cluster quietly (``quiet_shutdown``), so it ends in one line.
    """
    from distributed import Client, LocalCluster
    out = sys.stderr if out is None else out
    if scheduler:
        check_scheduler(scheduler)
        with Client(scheduler, timeout=f'{CONNECT_TIMEOUT_S}s') as client, quiet_shutdown():
            print(f'dask: scheduler {scheduler}, {len(client.scheduler_info()["workers"])} '
                  f'workers, dashboard {client.dashboard_link}', file=out)
            yield client
        return
    check_workers(workers)
    n = workers or os.cpu_count() or 1
    try:
        with _sigint_ignored():    # inherited by the worker processes started here
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   dashboard_address=':0')
    except Exception as e:   # noqa: B902 - any failure to start is one line
        raise FleetSetupError(f'cannot start a local Dask cluster of {n} worker processes '
                              f'({type(e).__name__}: {str(e)[:200]}); try fewer --workers '
                              'or check the machine\'s memory and open-file limits') from None
    with cluster, Client(cluster) as client, quiet_shutdown(cluster):
        print(f'dask: LocalCluster of {n} worker processes, dashboard '
              f'{client.dashboard_link}', file=out)
        yield client


@contextmanager
def _sigint_ignored():
    import signal
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:        # not the main thread: nothing to change
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


@contextmanager
def quiet_shutdown(cluster=None):
    """On Ctrl-C/SIGTERM, stop the job without Dask's tracebacks and warnings.

    Closing a cluster mid-job makes the scheduler, nannies, workers and client log every
    cancelled task and lost connection; the user asked to stop, so only the CLI's one line
    shows: this process's Dask loggers are silenced and the LocalCluster's worker processes
    (``cluster``) are killed before the cluster is closed (their results are not wanted).
    """
    import logging
    import signal
    try:
        yield
    except KeyboardInterrupt:
        for name in ('distributed', 'tornado', 'asyncio', 'bokeh'):
            logging.getLogger(name).setLevel(logging.CRITICAL + 1)
        for nanny in (getattr(cluster, 'workers', None) or {}).values():
            pid = getattr(getattr(getattr(nanny, 'process', None), 'process', None), 'pid',
                          None)
            try:
                if pid:
                    os.kill(pid, signal.SIGKILL)
            except OSError:
                pass
        raise


def _progress(futures, enabled):
    if enabled is None:
        enabled = sys.stderr.isatty()
    if enabled and futures:
        from distributed import progress
        progress(futures)
        print(file=sys.stderr)


def run_fleet(client, paths, group, reduce_fn, collect_kw=None, period_days=0.0,
              progress=None):
    """Map every log, reduce per sensor (and period); returns (units, failed logs).

    ``units`` is a list of UnitResult in (sensor, time) order; ``failed`` the LogResult
    headers of logs that could not be read and whose sensor is unknown.
    """
    collect_kw = dict(collect_kw or {})
    maps = client.map(collect_log, list(paths), group=group, pure=False, **collect_kw)
    heads_f = client.map(header, maps, pure=False)
    _progress(maps, progress)
    heads = client.gather(heads_f)
    by_path = dict(zip((h.path for h in heads), maps))
    failed = [h for h in heads if h.error and not h.sensor]
    known = [h for h in heads if h.sensor]
    keys = period_key(known, period_days)
    groups = {}
    for h in sorted(known, key=lambda h: (h.start_ns, h.path)):
        groups.setdefault(keys[h.path], []).append(h)
    reduces = [client.submit(reduce_unit, sensor, reduce_fn, hs,
                             *[by_path[h.path] for h in hs], pure=False)
               for (sensor, _), hs in sorted(groups.items())]
    _progress(reduces, progress)
    units = client.gather(reduces)
    return units, failed
