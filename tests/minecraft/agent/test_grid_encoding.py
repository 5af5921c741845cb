"""The observation vector's documented layout, on a real world server's observation and
on a hand-written one."""

from __future__ import annotations

import math

import numpy as np

from minecraft.agent import grid_encoding
from tests.minecraft.conftest import GROUND


def _info(**over: object) -> dict:
    names = ["air"] * grid_encoding.CUBE_CELLS
    info = {
        "XPos": 10.5,
        "YPos": 4.0,
        "ZPos": -3.5,
        "Yaw": 90.0,
        "Pitch": 45.0,
        "Life": 10.0,
        "Food": 15,
        "cube": names,
        "entities": [
            {"name": "graft", "x": 10.5, "y": 4.0, "z": -3.5},  # the agent: not an item
            {"name": "Pig", "x": 11.5, "y": 4.0, "z": -3.5, "life": 10.0},  # not an item
            {"name": "log", "x": 14.5, "y": 4.0, "z": -3.5, "quantity": 1},
            {"name": "dirt", "x": 10.5, "y": 5.6, "z": -3.5, "quantity": 2},
        ],
    }
    info.update(over)
    return info


def test_layout_of_stats_cube_and_items() -> None:
    names = ["air"] * grid_encoding.CUBE_CELLS
    names[(0 + 7) * 225 + (0 + 7) * 15 + (1 + 7)] = "stone"  # dx=1, dy=0, dz=0
    names[(-1 + 7) * 225 + (2 + 7) * 15 + (0 + 7)] = "log"  # dx=0, dy=-1, dz=2
    names[(3 + 7) * 225 + (0 + 7) * 15 + (0 + 7)] = "water"  # liquids are empty
    names[0] = "some_modded_block"  # unknown -> full
    v = grid_encoding.encode(_info(cube=names), k=3)
    assert v.shape == (grid_encoding.size(3),) == (8 + 3375 + 12,)
    assert v.dtype == np.float32
    np.testing.assert_allclose(
        v[:8],
        [10.5 / 64, 4 / 64, -3.5 / 64, math.sin(math.pi / 2), math.cos(math.pi / 2), 0.5, 0.5,
         0.75],
        atol=1e-6,
    )  # fmt: skip
    cube = v[8 : 8 + grid_encoding.CUBE_CELLS]
    assert set(np.unique(cube)) == {0.0, 1.0}
    assert cube.sum() == 3
    assert v[grid_encoding.cube_offset(1, 0, 0)] == 1.0
    assert v[grid_encoding.cube_offset(0, -1, 2)] == 1.0
    assert v[grid_encoding.cube_offset(0, 3, 0)] == 0.0
    assert v[grid_encoding.cube_offset(-7, -7, -7)] == 1.0
    items = v[grid_encoding.items_offset() :].reshape(3, 4)
    # Nearest first: the dirt 1.6 above, then the log 4 east; the third slot is empty.
    np.testing.assert_allclose(items[0], [0, 1.6 / 16, 0, 1], atol=1e-6)
    np.testing.assert_allclose(items[1], [4 / 16, 0, 0, 1], atol=1e-6)
    np.testing.assert_array_equal(items[2], [0, 0, 0, 0])


def test_encodes_a_real_server_observation(sync_client) -> None:
    client = sync_client(grid_radius=7, decorators='<DrawBlock x="1" y="4" z="0" type="stone"/>')
    r = client.step("move 0")
    v = grid_encoding.encode(r.info, k=2)
    assert v.shape == (grid_encoding.size(2),)
    assert v[grid_encoding.cube_offset(1, 0, 0)] == 1.0  # the drawn stone, east of the agent
    assert v[grid_encoding.cube_offset(0, -1, 0)] == 1.0  # the grass under the agent
    assert v[grid_encoding.cube_offset(0, 0, 0)] == 0.0  # the agent's own block
    assert v[grid_encoding.cube_offset(0, 1, 0)] == 0.0
    assert v[1] == GROUND / 64


def test_block_ids_follow_the_block_table_and_unknown_names_are_full() -> None:
    from minecraft import blocks as B

    names = ["air", "stone", "water", "no_such_block", "torch", "dirt"]
    ids = grid_encoding.block_ids(names)
    assert ids.dtype == np.int16
    assert ids.tolist() == [B.ID["air"], B.ID["stone"], B.ID["water"],
                            grid_encoding.UNKNOWN_FULL, B.ID["torch"], B.ID["dirt"]]  # fmt: skip
    occupancy = grid_encoding.FULL_BY_ID[ids]
    assert occupancy.tolist() == [0.0, 1.0, 0.0, 1.0, 0.0, 1.0]  # liquids, torches: empty


def test_cube_matches_a_per_block_lookup_on_every_known_name() -> None:
    from minecraft import blocks as B

    rng = np.random.default_rng(0)
    names = [*B.NAMES, "unknown_a"]
    grid = [names[i] for i in rng.integers(len(names), size=grid_encoding.CUBE_CELLS)]
    info = {"XPos": 0, "YPos": 0, "ZPos": 0, "Yaw": 0, "Pitch": 0, "cube": grid}
    cube = grid_encoding.encode(info, k=0)[len(grid_encoding.STATS) :]
    expected = [float(B.SOLID[B.ID[n]]) if n in B.ID else 1.0 for n in grid]
    assert cube.tolist() == expected


def test_grid_info_decodes_as_json_does_and_the_grid_only_when_it_changed(monkeypatch) -> None:
    """`GridInfo` gives what `json.loads` gives, with the grid's ids instead of names,
    wherever the grid stands among the keys; it decodes a grid only when its text differs
    from the last one's."""
    import json

    rng = np.random.default_rng(1)
    names = ["air", "stone", "water", "some_modded_block"]
    grids = [[names[i] for i in rng.integers(4, size=grid_encoding.CUBE_CELLS)] for _ in (0, 1)]
    decode = grid_encoding.GridInfo("cube")
    block_ids = grid_encoding.block_ids
    calls: list[int] = []

    def counted(names: list[str]) -> np.ndarray:
        calls.append(1)
        return block_ids(names)

    for step, (grid, order) in enumerate([(0, "first"), (0, "last"), (1, "middle"), (1, "last")]):
        info = _info(cube=grids[grid], TotalTime=step)
        keys = [k for k in info if k != "cube"]
        keys.insert({"first": 0, "middle": 3, "last": len(keys)}[order], "cube")
        raw = json.dumps({k: info[k] for k in keys}, separators=(",", ":")).encode()
        with monkeypatch.context() as m:
            m.setattr(grid_encoding, "block_ids", counted)
            got = decode(raw)
        want = json.loads(raw)
        assert got["cube"].tolist() == block_ids(want.pop("cube")).tolist()
        assert {k: v for k, v in got.items() if k != "cube"} == want
        np.testing.assert_array_equal(grid_encoding.encode(got), grid_encoding.encode(info))
    assert len(calls) == 2  # the two grids, each once
    assert decode(b'{"XPos":1}') == {"XPos": 1}  # no grid: decoded whole
