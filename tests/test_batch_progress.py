"""Batch progress on a non-terminal stream: a line per finished recording, status lines."""

import io

from forestslam.batch.job import empty_row, failed_row
from forestslam.batch.progress import BatchProgress


def test_status_lines_count_recordings_and_scans():
    stream = io.StringIO()  # not a terminal: plain lines, every 5 s
    progress = BatchProgress(total=4, skipped=1, stream=stream)
    assert progress.due() and progress.interval_s == 5.0
    progress.show(running=2, queued=1, running_scans=100)
    assert not progress.due()  # the next line only after interval_s
    ok = empty_row("a", "ok")
    ok.update(scans=300, scans_per_s=30.0)
    progress.finished(ok)
    progress.finished(failed_row("b", "b.bag: file not found"))
    progress.show(running=0, queued=0)
    progress.close()
    lines = stream.getvalue().splitlines()
    assert lines[0].startswith(
        "batch: 0/4 recordings (0 done, 0 failed, 2 running, 1 queued, 1 finished earlier); "
        "100 scans"
    )
    assert lines[1] == "a: ok, 300 scans (30.0 scans/s)"
    assert lines[2] == "b: failed: b.bag: file not found"
    assert lines[3].startswith("batch: 2/4 recordings (1 done, 1 failed, 0 running, 0 queued")
    assert "; 300 scans," in lines[3] and len(lines) == 4


def test_disabled_progress_prints_nothing():
    stream = io.StringIO()
    progress = BatchProgress(total=1, skipped=0, enabled=False, stream=stream)
    progress.finished(failed_row("a", "x"))
    progress.show(running=0, queued=0)
    assert stream.getvalue() == "" and not progress.due()
