"""Run a batch plan on a ``dask.distributed`` cluster.

A plan (``demsketch batch plan`` or :func:`demsketch.batch_plan`) is a list of
independent groups of edits, addressable by index, that share no tile.
:func:`run_plan` submits one task per group index; each task runs its group
on a worker exactly as ``demsketch batch run --plan PLAN --index N`` does
(its edits in manifest order, each journalled: a pending record with the
digests of its tiles before it starts, its tiles renamed into place, then a
done record), writing that group's tiles into the output; the client then
commits the batch as ``demsketch batch finish`` does (every interrupted edit
journal finished, temporary files of dead runs removed, the summary written)
and checks that every edit is done.

A task that raises is retried by Dask (``retries``); a task whose worker
process dies (killed, out of memory) is run again on another worker by the
scheduler (up to ``distributed.scheduler.allowed-failures`` times). Either
way the batch journal makes a retried group skip the edits it had finished
and never apply an edit twice, so the tiles are the same bytes as running
the indices one by one (or the whole batch in one process). Every worker
must see the plan's output directory at the same path (a shared file
system).
"""

import os
import uuid

from distributed import get_client

from . import DemsketchError, batch_finish, batch_groups, batch_run

__all__ = ["run_group", "run_plan"]


def run_group(plan, index, lock_timeout=300.0):
    """The task of one group: :func:`demsketch.batch_run` (on a worker)."""
    return batch_run(plan, index, lock_timeout=lock_timeout)


def run_plan(plan, client=None, *, retries=3, lock_timeout=300.0):
    """Run every group of ``plan`` on ``client``'s cluster, then finish the batch.

    ``client``: a ``distributed.Client`` (default: the current one).
    ``retries``: how many times Dask runs a group again whose task raised.
    Returns the batch summary (a dict, as :func:`demsketch.batch_finish`);
    raises :class:`demsketch.DemsketchError` when an edit is not done or a
    group failed after its retries (the summary in the output's state
    directory says which), and an edit that failed on its input is in the
    summary's ``failed`` count, as with the command.
    """
    if client is None:
        client = get_client()
    plan = os.path.abspath(os.fspath(plan))
    n = batch_groups(plan)
    # Keys unique to this run, so that a second run of the same plan (to
    # finish what a failed one left) is not answered from the first's.
    token = uuid.uuid4().hex[:12]
    keys = [f"demsketch-group-{i}-{token}" for i in range(n)]
    futures = client.map(
        run_group,
        [plan] * n,
        range(n),
        [lock_timeout] * n,
        key=keys,
        retries=retries,
        pure=False,
    )
    client.gather(futures)
    summary = batch_finish(plan, lock_timeout=lock_timeout)
    if summary["incomplete"]:
        raise DemsketchError(
            f"{summary['out']}: {len(summary['incomplete'])} edits not done "
            f"(groups {summary['incomplete_groups']}); run the plan again"
        )
    return summary
