"""The folder formats' one reader each, the one atomic write, and a worker pool that ends only its own."""

from __future__ import annotations

import json
import multiprocessing
import os
import stat
import time

import pytest

from fxswarm.runtime.campaign_folder import RUNS, FolderError, read_runs
from fxswarm.runtime.files import write_atomic
from fxswarm.study.parallel import completed


def test_an_atomic_write_replaces_the_file_whole_and_leaves_nothing_beside_it(tmp_path):
    path = tmp_path / "summary.json"
    path.write_text("old")
    write_atomic(path, "new")
    assert path.read_text() == "new" and os.listdir(tmp_path) == ["summary.json"]
    key = write_atomic(tmp_path / "agent-1.key", b"secret", private=True)
    assert stat.S_IMODE(key.stat().st_mode) == 0o600 and key.read_bytes() == b"secret"
    with pytest.raises(TypeError):
        write_atomic(path, 42)  # fails mid-write: the old file stays, the temporary one goes
    assert path.read_text() == "new" and sorted(os.listdir(tmp_path)) == ["agent-1.key", "summary.json"]


def test_the_campaign_reader_leaves_out_a_torn_line_and_refuses_a_broken_one(tmp_path):
    path = tmp_path / RUNS
    lines = [json.dumps({"id": i, "campaign": "f1"}) + "\n" for i in ("a", "b", "a")]
    path.write_text("".join(lines) + '{"id": "c", "camp')
    assert list(read_runs(tmp_path)) == ["a", "b"]  # the first line of an id wins; the torn one is no run
    assert path.read_text().endswith('"camp')  # only the writer repairs the file
    assert list(read_runs(tmp_path, "f1", repair=True)) == ["a", "b"] and path.read_text() == "".join(lines)
    path.write_text(lines[0] + "not json\n" + lines[1])
    with pytest.raises(FolderError, match=r"runs.jsonl:2: expected a JSON line"):
        read_runs(tmp_path)


def test_the_worker_pool_ends_its_own_workers_only(tmp_path):
    bystander = multiprocessing.get_context("spawn").Process(target=time.sleep, args=(120,))
    bystander.start()  # a child of the caller's that the campaign did not start
    try:
        results = dict(completed(time.sleep, [(0.0,)] * 4, workers=2))
        assert sorted(results) == [0, 1, 2, 3]
        assert bystander.is_alive() and bystander in multiprocessing.active_children()
        assert multiprocessing.active_children() == [bystander]  # the pool's workers are gone
    finally:
        bystander.terminate()
        bystander.join(10)


def test_report_refuses_a_campaign_folder_with_a_broken_line_naming_it(tmp_path, capsys):
    import argparse

    from fxswarm.report import main

    (tmp_path / "campaign.json").write_text("{}")
    (tmp_path / RUNS).write_text('{"id": "a"}\nnot json\n')
    assert main(argparse.Namespace(dir=str(tmp_path))) == 2
    assert f"{tmp_path / RUNS}:2: expected a JSON line" in capsys.readouterr().err
