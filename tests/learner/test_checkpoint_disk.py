"""A checkpoint the disk has no room for: DiskFull naming the file and the space left, no
temporary file left, the checkpoints before it whole; stale temporaries removed."""

from __future__ import annotations

import pytest
import torch

from learner.checkpoint import (
    DiskFull,
    latest_checkpoint,
    load_checkpoint,
    remove_stale_temporaries,
    save_checkpoint,
)
from tests.tools.small_disk import small_disk


@pytest.mark.service  # a subprocess: a server, a mount or a cgroup
def test_a_full_disk_leaves_the_last_good_checkpoint_and_no_temporary(tmp_path) -> None:
    with small_disk(tmp_path / "disk", "256k") as disk:
        folder = disk / "checkpoints"
        small = {"w": torch.zeros(1000)}  # 4 KB
        good = save_checkpoint(folder, small, updates=1)
        with pytest.raises(DiskFull) as raised:
            save_checkpoint(folder, {"w": torch.zeros(200_000)}, updates=2)  # 800 KB
        assert raised.value.path == folder / "ckpt-000000002.pt.tmp"
        assert 0 <= raised.value.free < 256 * 1024
        assert sorted(p.name for p in folder.iterdir()) == ["ckpt-000000001.pt"]
        assert latest_checkpoint(folder) == good
        assert torch.equal(load_checkpoint(good)["w"], small["w"])


def test_stale_temporaries_are_removed_and_checkpoints_kept(tmp_path) -> None:
    folder = tmp_path / "checkpoints"
    kept = save_checkpoint(folder, {"w": torch.ones(3)}, updates=5)
    stale = folder / "ckpt-000000010.pt.tmp"
    stale.write_bytes(b"half a checkpoint")
    assert remove_stale_temporaries(folder) == [stale]
    assert sorted(folder.iterdir()) == [kept]
    assert remove_stale_temporaries(tmp_path / "absent") == []
