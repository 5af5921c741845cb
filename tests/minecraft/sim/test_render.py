"""Frames drawn at the same time in several threads (world servers of one process each
render in their own thread) show each one's own world."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import pytest

from minecraft.compiled import compile_lock
from minecraft.malmo.mission import parse_mission
from minecraft.malmo.mission_xml import mission_xml
from minecraft.sim.render import render
from minecraft.sim.world import World
from tests.minecraft.conftest import FLAT, GROUND

REPO = Path(__file__).resolve().parents[3]


def _world(block: str) -> World:
    wall = f'<DrawCuboid x1="-3" y1="4" z1="3" x2="3" y2="7" z2="3" type="{block}"/>'
    xml = mission_xml(flat=FLAT, placement=(0.5, GROUND, 0.5), decorators=wall, grid_radius=0)
    return World(parse_mission(xml), 0)


def test_frames_rendered_in_parallel_threads_show_their_own_world() -> None:
    worlds = [_world("gold_block"), _world("lapis_block")]
    expected = [render(w, 48, 48) for w in worlds]
    assert expected[0] != expected[1]
    wrong: list[int] = []

    def draw(k: int) -> None:
        for _ in range(40):
            if render(worlds[k], 48, 48) != expected[k]:
                wrong.append(k)

    threads = [threading.Thread(target=draw, args=(k,)) for k in (0, 1, 0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert wrong == []


@pytest.mark.service  # a child process
def test_world_servers_compile_the_frame_kernels_one_at_a_time() -> None:
    # A second process waits while the first holds the compile lock (the first writes
    # numba's cache; the second then loads it instead of compiling too).
    code = (
        "from minecraft.sim import render; print('imported', flush=True); "
        "render.warm_up(); print('compiled', flush=True)"
    )
    with compile_lock("render"):
        child = subprocess.Popen(
            [sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=REPO
        )
        assert child.stdout is not None
        assert child.stdout.readline() == "imported\n"
        with pytest.raises(subprocess.TimeoutExpired):
            child.wait(timeout=1.0)  # held at the lock
    assert child.stdout.readline() == "compiled\n"
    assert child.wait(timeout=120) == 0
