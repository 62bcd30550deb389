"""Contract section 3: every recording the project writes carries chunk and message indexes and
its summary: the committed recordings, a fresh ``simulate``, a ``replay --out`` (the node's own
recording: the same writer as the live node's), a ``recover``ed copy (issue 34 item 1). Checked
on the bytes (``mcap_spec.check_indexed``); an old file without message indexes is refused."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import small_campaign
from mcap_spec import check_indexed

from node.cli import main
from simulator.export import write_recording

RECORDINGS = Path(__file__).resolve().parents[1] / "recordings"


@pytest.fixture(scope="module")
def campaign(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return small_campaign(tmp_path_factory.mktemp("idx"), seed=9)


@pytest.mark.parametrize("name", ["engine1_runs.mcap", "engine1_fault.mcap"])
def test_the_committed_recordings_are_indexed(name: str) -> None:
    assert check_indexed(RECORDINGS / name) > 100_000


def test_every_writer_path_indexes_its_recording(campaign: Path, tmp_path: Path) -> None:
    assert check_indexed(campaign / "train.mcap") > 0  # simulate
    out, copy = tmp_path / "node.mcap", tmp_path / "copy.mcap"
    assert main(["replay", str(campaign / "test.mcap"), "--model", str(campaign / "m"), "--out", str(out),
                 "--workers", "0", "--quiet"]) == 0
    n = check_indexed(out)
    assert main(["recover", str(out), "--out", str(copy), "--quiet"]) == 0
    assert check_indexed(copy) == n


def test_a_recording_without_message_indexes_is_refused(tmp_path: Path) -> None:
    """The check itself can fail: the simulator's writer without them (as before session 16)."""
    from simulator.campaign import simulate_campaign

    campaign = simulate_campaign(runs=1, seed=3, plateau_scale=0.05)
    path = tmp_path / "bare.mcap"
    write_recording(campaign, path, "bed1", 3, message_index=False)
    with pytest.raises(AssertionError, match="lacks message indexes"):
        check_indexed(path)
    write_recording(campaign, tmp_path / "full.mcap", "bed1", 3)
    assert check_indexed(tmp_path / "full.mcap") > 0
