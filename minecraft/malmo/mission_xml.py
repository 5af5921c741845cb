"""Mission XML builders for the simulator and for a real Malmo Minecraft.

Every mission carries a VideoProducer: real Malmo never queues the commands of a mission
without one (each step waits 3 s and answers sent = 0). An agent that does not read
pixels gets a small one (``SMALL_VIDEO``), cheap to draw and to send.

``obtain_diamond()`` is the sample mission shipped beside this module as
``obtain_diamond.xml``: survival in a seeded default world, the observations the
obtain-diamond tree needs (full stats, a 15×15×15 grid named ``cube``, full inventory,
nearby entities, ray), every command handler it uses, a reward for the diamond and a
20-minute time limit.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

NS = "http://ProjectMalmo.microsoft.com"
SAMPLE_PATH = Path(__file__).with_name("obtain_diamond.xml")
SMALL_VIDEO = (32, 32)  # width, height of the frame of an agent that does not use pixels


def mission_xml(
    *,
    width: Optional[int] = 64,
    height: Optional[int] = 64,
    ms_per_tick: int = 50,
    time_limit_ms: Optional[int] = 1_200_000,
    seed: Optional[int] = None,
    diamond_keep: Optional[float] = None,
    flat: Optional[str] = None,
    grid_radius: int = 7,
    handlers: str = "continuous discrete inventory craft quit absolute",
    placement: Optional[tuple[float, float, float]] = None,
    inventory: tuple[tuple[int, str, int], ...] = (),
    decorators: str = "",
    rewards: str = "",
    observations: str = "stats inventory ray entities",
) -> str:
    """Build a mission XML string.

    Args:
        width: frame width, or None when the agent does not use pixels (``SMALL_VIDEO``).
        height: frame height (None: ``SMALL_VIDEO``).
        ms_per_tick: ModSettings/MsPerTick.
        time_limit_ms: ServerQuitFromTimeUp in game ms (50 per tick), None for none.
        seed: DefaultWorldGenerator seed (None lets the server choose).
        diamond_keep: the fraction of diamond veins the simulator's default world keeps
            (generatorOptions ``diamondKeep``; None: the server's setting).
        flat: a FlatWorldGenerator string instead of the default generator.
        grid_radius: half-size of the ``cube`` grid (0 for no grid).
        handlers: space-separated handler keys (continuous, discrete, inventory, craft,
            quit, absolute).
        placement: AgentStart Placement (x, y, z).
        inventory: starting (slot, item, quantity).
        decorators: raw DrawingDecorator children (``<DrawBlock .../>``...).
        rewards: raw AgentHandlers reward/quit elements.
        observations: space-separated producers besides the grid (stats, inventory,
            ray, entities).
    """
    gen = _world_generator(seed, flat, diamond_keep)
    deco = f"<DrawingDecorator>{decorators}</DrawingDecorator>" if decorators else ""
    limit = (
        f'<ServerQuitFromTimeUp timeLimitMs="{time_limit_ms}"/>'
        if time_limit_ms is not None
        else ""
    )
    place, inv = _agent_start(placement, inventory)
    obs = "".join(_PRODUCERS[k] for k in observations.split())
    grid, video = _grid(grid_radius), _video(width, height)
    cmd = "".join(_COMMANDS[k] for k in _COMMANDS if k in set(handlers.split()))
    return f"""<?xml version="1.0" encoding="UTF-8" standalone="no" ?>
<Mission xmlns="{NS}" xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance">
  <About><Summary>graft: obtain a diamond</Summary></About>
  <ModSettings><MsPerTick>{ms_per_tick}</MsPerTick></ModSettings>
  <ServerSection>
    <ServerInitialConditions>
      <Time><StartTime>1000</StartTime><AllowPassageOfTime>true</AllowPassageOfTime></Time>
    </ServerInitialConditions>
    <ServerHandlers>
      {gen}{deco}
      {limit}
      <ServerQuitWhenAnyAgentFinishes/>
    </ServerHandlers>
  </ServerSection>
  <AgentSection mode="Survival">
    <Name>graft</Name>
    <AgentStart>{place}{inv}</AgentStart>
    <AgentHandlers>
      {obs}
      {grid}
      {video}
      {cmd}
      {rewards}
    </AgentHandlers>
  </AgentSection>
</Mission>
"""


_PRODUCERS = {
    "stats": "<ObservationFromFullStats/>",
    "inventory": '<ObservationFromFullInventory flat="false"/>',
    "ray": "<ObservationFromRay/>",
    "entities": "<ObservationFromNearbyEntities>"
    '<Range name="entities" xrange="16" yrange="8" zrange="16"/>'
    "</ObservationFromNearbyEntities>",
}
"""The observation producers `mission_xml` names, as their XML."""
_COMMANDS = {
    "continuous": '<ContinuousMovementCommands turnSpeedDegs="180"/>',
    "discrete": (
        '<DiscreteMovementCommands><ModifierList type="allow-list">'
        "<command>movenorth</command><command>movesouth</command>"
        "<command>moveeast</command><command>movewest</command>"
        "<command>jumpnorth</command><command>jumpsouth</command>"
        "<command>jumpeast</command><command>jumpwest</command>"
        "<command>look</command></ModifierList></DiscreteMovementCommands>"
    ),
    "absolute": "<AbsoluteMovementCommands/>",
    "inventory": "<InventoryCommands/>",
    "craft": "<SimpleCraftCommands/>",
    "quit": "<MissionQuitCommands/>",
}
"""The command handlers `mission_xml` names, as their XML, in the order they are written."""


def _world_generator(
    seed: Optional[int], flat: Optional[str], diamond_keep: Optional[float] = None
) -> str:
    if flat is not None:
        return f'<FlatWorldGenerator generatorString="{flat}" forceReset="true"/>'
    seed_attr = f' seed="{seed}"' if seed is not None else ""
    if diamond_keep is not None:
        seed_attr += f" generatorOptions='{{\"diamondKeep\": {float(diamond_keep)!r}}}'"
    return f'<DefaultWorldGenerator forceReset="true"{seed_attr}/>'


def _agent_start(
    placement: Optional[tuple[float, float, float]], inventory: tuple[tuple[int, str, int], ...]
) -> tuple[str, str]:
    """The AgentStart's Placement and Inventory elements (empty where not given)."""
    place = ""
    if placement is not None:
        place = '<Placement x="{}" y="{}" z="{}" yaw="0" pitch="0"/>'.format(*placement)
    inv = ""
    if inventory:
        items = "".join(
            f'<InventoryItem slot="{s}" type="{t}" quantity="{q}"/>' for s, t, q in inventory
        )
        inv = f"<Inventory>{items}</Inventory>"
    return place, inv


def _grid(radius: int) -> str:
    """The ``cube`` grid observation of half-size `radius` (none for 0)."""
    if radius <= 0:
        return ""
    r = radius
    return (
        f'<ObservationFromGrid><Grid name="cube"><min x="-{r}" y="-{r}" z="-{r}"/>'
        f'<max x="{r}" y="{r}" z="{r}"/></Grid></ObservationFromGrid>'
    )


def _video(width: Optional[int], height: Optional[int]) -> str:
    if width is None or height is None:
        width, height = SMALL_VIDEO
    return (
        f'<VideoProducer want_depth="false"><Width>{width}</Width>'
        f"<Height>{height}</Height></VideoProducer>"
    )


def obtain_diamond(
    seed: Optional[int] = None, *, pixels: bool = True, diamond_keep: Optional[float] = None
) -> str:
    """The sample obtain-diamond mission (reward 1 per log ... 1024 for the diamond);
    ``pixels=False``: the small frame, for an agent that reads observations only;
    ``diamond_keep``: the fraction of diamond veins the world keeps (``mission_xml``)."""
    rewards = (
        "<RewardForCollectingItem>"
        '<Item type="log" reward="1"/><Item type="planks" reward="2"/>'
        '<Item type="stick" reward="4"/><Item type="crafting_table" reward="4"/>'
        '<Item type="wooden_pickaxe" reward="8"/><Item type="cobblestone" reward="16"/>'
        '<Item type="stone_pickaxe" reward="32"/><Item type="iron_ore" reward="64"/>'
        '<Item type="furnace" reward="32"/><Item type="iron_ingot" reward="128"/>'
        '<Item type="iron_pickaxe" reward="256"/><Item type="diamond" reward="1024"/>'
        "</RewardForCollectingItem>"
        '<AgentQuitFromCollectingItem><Item type="diamond"/></AgentQuitFromCollectingItem>'
    )
    # No AbsoluteMovementCommands: teleporting would make the quest trivial.
    size = 64 if pixels else None
    return mission_xml(
        width=size, height=size, seed=seed, rewards=rewards, diamond_keep=diamond_keep,
        handlers="continuous discrete inventory craft quit",
    )  # fmt: skip
