"""Which parts of a Malmo mission the simulator implements, which it refuses, and what it
approximates.

Every handler, decorator and draw element Malmo's schema defines is either in
``IMPLEMENTED`` or in ``REFUSED`` with a reason: a mission that uses a refused one is
refused at MissionInit (reply 0, the reason naming the element), never run with the
handler silently ignored. ``check`` also refuses what the simulator cannot build (game
modes other than Survival and Creative, third-person video, mobs it does not have, fire and portals,
worlds too large) and returns warnings for what it approximates (blocks whose shape or
mechanism is simplified, weather, mob spawning, colours and variants).
"""

from __future__ import annotations

from minecraft import approximate_blocks
from minecraft import blocks as B
from minecraft.malmo.mission import Mission, MissionError
from minecraft.sim import decorators, extent, worldgen
from minecraft.sim.decorators.build_battle import volume
from minecraft.sim.entities import MOBS

IMPLEMENTED: frozenset[str] = frozenset(
    """
    FlatWorldGenerator DefaultWorldGenerator DrawingDecorator MazeDecorator ClassroomDecorator
    BuildBattleDecorator ServerQuitFromTimeUp
    ServerQuitWhenAnyAgentFinishes
    DrawObjectType DrawBlock DrawCuboid DrawSphere DrawLine DrawItem DrawEntity
    ObservationFromFullStats ObservationFromFullInventory ObservationFromGrid
    ObservationFromNearbyEntities ObservationFromRay ObservationFromHotBar
    ObservationFromDistance ObservationFromRecentCommands ObservationFromChat VideoProducer
    ObservationFromSubgoalPositionList
    ContinuousMovementCommands AbsoluteMovementCommands DiscreteMovementCommands
    InventoryCommands ChatCommands SimpleCraftCommands MissionQuitCommands TurnBasedCommands
    RewardForTouchingBlockType RewardForSendingCommand RewardForCollectingItem
    RewardForDiscardingItem RewardForReachingPosition RewardForMissionEnd RewardForTimeTaken
    RewardForDamagingEntity RewardForSendingMatchingChatMessage RewardForCatchingMob
    RewardForStructureCopying
    AgentQuitFromTimeUp AgentQuitFromReachingPosition AgentQuitFromTouchingBlockType
    AgentQuitFromCollectingItem AgentQuitFromReachingCommandQuota AgentQuitFromCatchingMob
    """.split()
)

_NOT = "the simulator does not implement it"
REFUSED: dict[str, str] = {
    "FileWorldGenerator": "saved worlds cannot be loaded",
    "BiomeGenerator": "single-biome worlds are not generated",
    "AnimationDecorator": _NOT,
    "SnakeDecorator": _NOT,
    "MovingTargetDecorator": _NOT,
    "NavigationDecorator": _NOT,
    "DrawContainer": "containers and their contents are not simulated",
    "DrawSign": "signs are not simulated",
    "EnderBoxInventory": "ender chest inventories are not simulated",
    "ObservationFromDiscreteCell": _NOT,
    "ObservationFromTurnScheduler": _NOT,
    "ObservationFromHuman": "there is no human player",
    "ObservationFromSystem": _NOT,
    "ObservationFromCompass": "compasses are not simulated",
    "DepthProducer": "only VideoProducer frames are produced (use want_depth)",
    "LuminanceProducer": "only VideoProducer frames are produced",
    "ColourMapProducer": "only VideoProducer frames are produced",
    "RewardForPossessingItem": _NOT,
    "RewardForCraftingItem": _NOT,
    "RewardForSmeltingItem": _NOT,
    "NearbyCraftCommands": _NOT + " (use SimpleCraftCommands)",
    "NearbySmeltCommands": _NOT + " (use SimpleCraftCommands)",
    "PlaceCommands": _NOT,
    "HumanLevelCommands": "there is no human player",
    "AgentQuitFromPossessingItem": _NOT,
    "AgentQuitFromCraftingItem": _NOT,
    "AgentQuitFromSmeltingItem": _NOT,
}


def check(mission: Mission) -> list[str]:
    """Refuse a mission the simulator cannot run faithfully; list what it approximates.

    Returns:
        Warnings, one per approximation (empty when none).

    Raises:
        MissionError: naming the first refused element or value and why.
    """
    for name in sorted(mission.elements & REFUSED.keys()):
        raise MissionError(f"<{name}> is refused: {REFUSED[name]}")
    if mission.mode not in ("Survival", "Creative"):
        raise MissionError(
            f'<AgentSection mode="{mission.mode}"> is refused: only Survival and Creative'
        )
    bb = mission.build_battle
    if bb is not None and volume(bb.goal) != volume(bb.player):
        raise MissionError(
            "<BuildBattleDecorator> is refused: the goal and player structure bounds hold "
            f"{volume(bb.goal)} and {volume(bb.player)} blocks (they must match)"
        )
    if mission.viewpoint != 0:
        raise MissionError(
            f'<VideoProducer viewpoint="{mission.viewpoint}"> is refused: first person only'
        )
    blocks = set(mission.block_types()) | decorators.block_types(mission)
    if mission.flat_generator is not None:
        try:
            blocks.update(B.NAMES[b] for b in worldgen.flat_layers(mission.flat_generator))
        except (ValueError, KeyError) as e:
            raise MissionError(f"<FlatWorldGenerator generatorString>: {e}") from None
    for name in sorted(blocks & approximate_blocks.REFUSED.keys()):
        raise MissionError(f"block {name!r} is refused: {approximate_blocks.REFUSED[name]}")
    for op in mission.drawing:
        if op.kind == "entity" and op.type not in MOBS:
            raise MissionError(
                f'<DrawEntity type="{op.type}"> is refused: the simulator has only '
                + ", ".join(sorted(MOBS))
            )
    try:
        extent.check(mission)
    except ValueError as e:
        raise MissionError(str(e)) from None
    return _warnings(mission, blocks)


def _warnings(mission: Mission, blocks: set[str]) -> list[str]:
    out = []
    by_category: dict[str, list[str]] = {}
    for name in sorted(blocks & approximate_blocks.NOTES.keys()):
        by_category.setdefault(approximate_blocks.NOTES[name], []).append(name)
    for category, names in sorted(by_category.items()):
        out.append(f"{', '.join(names)}: {approximate_blocks.CATEGORIES[category]}")
    if mission.weather not in ("normal", "clear"):
        out.append(f"Weather {mission.weather}: weather is not simulated")
    if mission.allow_spawning:
        out.append("AllowSpawning true: no mobs spawn during a mission")
    if mission.mode == "Creative":
        out.append(
            "mode Creative: no damage but the void's, no hunger, blocks break at once and "
            "drop nothing, placed blocks are not used up; flying is not simulated"
        )
    if mission.colour_or_variant:
        out.append("colour and variant attributes are not simulated (blocks keep one look)")
    return out
