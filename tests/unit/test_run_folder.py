"""The run folder's write check at start-up, as several processes of one run make it at once."""

import threading

from fxswarm.runtime.output import prepare_run_folder


def test_processes_checking_one_run_folder_at_once_do_not_trip_over_each_other(tmp_path):
    # Containers of one compose run share the folder and each runs fxswarm as pid 1, so a probe
    # file named by pid was the same file for all of them: one's clean-up removed another's probe
    # and that robot exited with "cannot write the run folder: No such file or directory".
    # Threads of one process share a pid too, which makes the same collision here.
    out = tmp_path / "run"
    failures: list[BaseException] = []

    def check() -> None:
        for _ in range(300):
            try:
                prepare_run_folder(out, "test")
            except BaseException as exc:  # noqa: BLE001 - SystemExit is what a collision raises
                failures.append(exc)
                return

    threads = [threading.Thread(target=check) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not failures, failures[:3]
    assert list(out.iterdir()) == []  # no probe left behind
