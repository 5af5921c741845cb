"""What one world server lets a client cost it: frame size, grid volume, message size,
connections and idle time. Each is a ``graft minecraft serve`` flag; each refusal is an
``error: ...`` reply naming the limit and its flag.

A mission over a limit is refused at MissionInit, before its world is built or a frame
drawn (a 2000×2000 frame is 12 MB and seconds of drawing per step under the world's
lock, and every other client of the server waits on that lock).
"""

from __future__ import annotations

from dataclasses import dataclass

from minecraft.malmo.mission import Mission, MissionError


@dataclass(frozen=True)
class Limits:
    """A world server's caps on what one client may cost it.

    Attributes:
        max_frame_pixels: VideoProducer Width × Height (800×600 by default, the largest of
            Malmo's sample missions: a 1.4 MB RGB frame, 1.9 MB with depth).
        max_grid_cells: ObservationFromGrid cells summed over a mission's grids (each
            cell is a block name in every observation's JSON).
        max_message_bytes: the longest request message (MissionInit XML included); a
            message is read as its bytes arrive, never allocated from its announced length.
        max_connections: open connections; one more is answered with an error and closed.
        idle_timeout_s: a connection that sends nothing for this long is answered with an
            error and closed (a mission it owns is quit).
    """

    max_frame_pixels: int = 800 * 600
    max_grid_cells: int = 100_000
    max_message_bytes: int = 4 * 1024 * 1024
    max_connections: int = 64
    idle_timeout_s: float = 300.0

    def __post_init__(self) -> None:
        for name in ("max_frame_pixels", "max_grid_cells", "max_message_bytes", "max_connections"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not self.idle_timeout_s > 0.0:
            raise ValueError(f"idle_timeout_s must be positive, got {self.idle_timeout_s}")

    def check(self, mission: Mission) -> None:
        """Refuse a mission over the frame or grid limit.

        Raises:
            MissionError: naming the element, its size, the limit and the flag.
        """
        pixels = mission.width * mission.height
        if mission.has_video and pixels > self.max_frame_pixels:
            raise MissionError(
                f"<VideoProducer> {mission.width}x{mission.height} is {pixels:,} pixels; this "
                f"server draws at most {self.max_frame_pixels:,} (--max-frame-pixels)"
            )
        cells = sum(grid_cells(g.lo, g.hi) for g in mission.grids)
        if cells > self.max_grid_cells:
            raise MissionError(
                f"<ObservationFromGrid> has {cells:,} cells; this server observes at most "
                f"{self.max_grid_cells:,} (--max-grid-cells)"
            )


def grid_cells(lo: tuple[int, int, int], hi: tuple[int, int, int]) -> int:
    """Cells of a grid with inclusive bounds."""
    return (hi[0] - lo[0] + 1) * (hi[1] - lo[1] + 1) * (hi[2] - lo[2] + 1)


DEFAULT_LIMITS = Limits()
