"""Batch plans run by `demsketch.dask` on a LocalCluster of two worker
processes, and as an array job in separate processes: the same tile bytes
as applying the edits one by one with `demsketch edit --in-place`, also
when a worker is killed in the middle of an edit (Dask runs its group
again; the batch journal keeps the edit from being applied twice)."""

import json
import os
import random
import subprocess
import sys

import pytest
from distributed import Client, LocalCluster

import demsketch
import demsketch.dask
from conftest import OPTIONS, digests


def cluster():
    return LocalCluster(
        n_workers=2,
        threads_per_worker=1,
        processes=True,
        dashboard_address=None,
        silence_logs=40,
    )


def check_summary(batch, s):
    assert s["edits"] == 6 and s["incomplete"] == [], s
    assert [r["id"] for r in s["records"]] == [f"e{k:02}" for k in range(6)]
    assert s["failed"] == 0 and s["below_min_fit"] == 0
    on_disk = json.loads((batch.state() / "summary.json").read_text())
    assert on_disk["records"] == s["records"]


def test_plan_on_a_local_cluster_gives_the_same_bytes(batch):
    batch.fresh()
    plan = demsketch.batch_plan(batch.dem, batch.manifest, batch.out, batch.plan, **OPTIONS)
    assert len(plan["groups"]) == 4 == demsketch.batch_groups(batch.plan)
    with cluster() as c, Client(c) as client:
        s = demsketch.dask.run_plan(batch.plan, client)
        # A second run of the finished plan (a resubmitted job) applies nothing twice.
        again = demsketch.dask.run_plan(batch.plan, client)
    assert digests(batch.out) == batch.want
    check_summary(batch, s)
    assert s["written"] == 6
    assert again["records"] == s["records"]


def test_a_worker_killed_mid_edit_is_retried_without_a_double_applied_edit(batch):
    batch.fresh()
    demsketch.batch_plan(batch.dem, batch.manifest, batch.out, batch.plan, **OPTIONS)
    with cluster() as c, Client(c) as client:
        workers = sorted(client.scheduler_info()["workers"])
        pids = client.run(os.getpid)
        # One worker SIGKILLs itself in its first edit's write-back, after
        # the edit's journal and before its first tile is renamed (the
        # library's test hook, read from the C environment at each commit;
        # the worker the nanny starts in its place has a clean one).
        client.run(os.putenv, "DEMSKETCH_TEST_ABORT_AFTER_RENAMES", "0", workers=[workers[0]])
        s = demsketch.dask.run_plan(batch.plan, client, retries=2)
        after = client.run(os.getpid)
    assert pids[workers[0]] not in after.values(), "the worker was not killed"
    assert digests(batch.out) == batch.want
    check_summary(batch, s)
    # The killed edit's tiles were committed from its journal when its
    # group ran again: recorded as recovered, not applied a second time.
    statuses = [r["status"] for r in s["records"]]
    assert statuses.count("recovered") == 1, statuses
    assert statuses.count("written") == 5, statuses


RUN_ONE = "import sys, demsketch; demsketch.batch_run(sys.argv[1], int(sys.argv[2]))"


def test_array_job_indices_in_a_shuffled_order_in_separate_processes(batch):
    batch.fresh()
    demsketch.batch_plan(batch.dem, batch.manifest, batch.out, batch.plan, **OPTIONS)
    order = list(range(demsketch.batch_groups(batch.plan)))
    random.Random(15).shuffle(order)
    assert order != sorted(order)
    # Two processes at a time, as an array job with two slots would.
    for k in range(0, len(order), 2):
        procs = [
            subprocess.Popen([sys.executable, "-c", RUN_ONE, str(batch.plan), str(i)],
                             stderr=subprocess.PIPE, text=True)
            for i in order[k:k + 2]
        ]
        for p in procs:
            _, err = p.communicate()
            assert p.returncode == 0, err
    s = demsketch.batch_finish(batch.plan)
    assert digests(batch.out) == batch.want
    check_summary(batch, s)
    assert s["written"] == 6


def test_batch_errors_are_one_line_exceptions(batch, tmp_path):
    batch.fresh()
    demsketch.batch_plan(batch.dem, batch.manifest, batch.out, batch.plan, **OPTIONS)
    with pytest.raises(demsketch.DemsketchError, match="group index 9 is out of range"):
        demsketch.batch_run(batch.plan, 9)
    with pytest.raises(demsketch.DemsketchError, match="already exists"):
        demsketch.batch_plan(batch.dem, batch.manifest, batch.out, tmp_path / "p.json")
    s = demsketch.batch_finish(batch.plan)
    assert len(s["incomplete"]) == 6
