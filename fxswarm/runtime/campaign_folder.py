"""A campaign's folder, read: the one reader of its format, for the campaign that resumes it
(:mod:`fxswarm.study.campaign_store`, which writes it) and for ``fxswarm report`` alike.

``spec.json``: which campaign the folder holds; ``runs.jsonl``: one JSON line per finished run,
appended whole as each finishes (a torn last line, should the machine die mid-write, is not a
run); ``campaign.json``: the statistics per cell and law.
"""

from __future__ import annotations

import json
from pathlib import Path

SPEC = "spec.json"
RUNS = "runs.jsonl"
RESULT = "campaign.json"


class FolderError(ValueError):
    """The folder's files are not a campaign's (or not this campaign's): the message names the
    file, the line and what was expected."""


def is_campaign(folder: Path) -> bool:
    return (Path(folder) / RESULT).is_file()


def read_runs(folder: Path, fingerprint: str | None = None, repair: bool = False) -> dict[str, dict]:
    """The runs in ``folder/runs.jsonl`` by id (the first line of an id wins), in file order.

    A torn last line is left out (``repair``: cut off the file, so that appending starts on a
    fresh line); any other line that is not JSON, or (``fingerprint`` given) a run of another
    campaign, raises :class:`FolderError`."""
    path = Path(folder) / RUNS
    if not path.is_file():
        return {}
    data = path.read_bytes()
    whole = data[: data.rfind(b"\n") + 1]
    if repair and len(whole) != len(data):  # a line cut short: the run it held is run again
        with open(path, "r+b") as fh:
            fh.truncate(len(whole))
    runs: dict[str, dict] = {}
    for number, line in enumerate(whole.decode().splitlines(), 1):
        try:
            record = json.loads(line)
        except ValueError:
            raise FolderError(f"{path}:{number}: expected a JSON line, got {line[:60]!r}") from None
        if fingerprint is not None and record.get("campaign") != fingerprint:
            raise FolderError(f"{path}:{number}: a run of another campaign ({record.get('campaign')!r}, "
                              f"expected {fingerprint!r}); use another --out")
        runs.setdefault(record["id"], record)
    return runs


def read_result(folder: Path) -> dict:
    """``folder/campaign.json``: the statistics (:class:`FolderError` if it is not JSON)."""
    path = Path(folder) / RESULT
    try:
        return json.loads(path.read_text())
    except ValueError:
        raise FolderError(f"{path}: expected a campaign's statistics (JSON); run the campaign again") from None
