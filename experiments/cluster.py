"""A Dask distributed cluster as a ``concurrent.futures`` executor: what ``python -m experiments
--cluster ADDRESS`` and ``python -m mission.simulate --scheduler ADDRESS`` run their tasks on.

The workers must be able to import this project (start them from a checkout with the project
installed: ``pip install -e '.[cluster]'``, then ``dask worker ADDRESS``) and read the files a
task names (a scenario file: the same path on every machine).
"""
from __future__ import annotations


class UsageError(Exception):
    """Bad command-line value; reported as one line with exit code 2."""


def connect(address: str, timeout_s: float, flag: str, setup=None, *args):
    """An executor on the Dask scheduler at ``address``; ``setup(*args)`` runs once on every
    worker before any task (e.g. loading the planners' compiled kernels).

    Returns:
        (client, executor, threads): the client to close at the end, the executor, and the number
        of worker threads the scheduler reports.

    Raises:
        UsageError, one line naming ``flag``: dask is not installed, the scheduler is unreachable,
            or no worker joined within ``timeout_s``.
    """
    try:
        from distributed import Client
    except ImportError:
        raise UsageError(f"{flag}: needs dask's distributed scheduler: pip install -e '.[cluster]'") from None
    try:
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as err:
        raise UsageError(f"{flag}: expected a reachable Dask scheduler at {address!r}, "
                         f"found none within {timeout_s:g} s ({type(err).__name__}: "
                         f"{str(err).splitlines()[0] if str(err) else ''})") from None
    try:
        client.wait_for_workers(1, timeout=timeout_s)
    except (OSError, TimeoutError):
        client.close()
        raise UsageError(f"{flag}: the scheduler at {address!r} has no worker after {timeout_s:g} s") from None
    if setup is not None:
        client.run(setup, *args)
    threads = sum(client.nthreads().values())
    # pure=False: every task runs (a task's result never comes from another's cache).
    return client, client.get_executor(pure=False), threads
