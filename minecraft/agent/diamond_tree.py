"""The obtain-diamond behaviour tree (paper sec. III-D) and the loop that runs it over
the Malmo protocol.

Shape (``graft minecraft tree`` prints it in full)::

    [o] Obtain diamond                        Selector: the first branch that acts wins
        [o] Survive                           out of water/lava, out of a fallen block,
                                              eat when hungry
        [o] Re-plan                           the watchdog fired (no progress): go up
                                              for wood when none is held, else explore
                                              elsewhere (``agent.watchdog``)
        [-] Pick up drops                     a wanted item lies near: walk onto it
        [-] Quest                             Sequence of backchained needs:
            [o] Wood                          enough wood for the whole quest, or gather logs
            [o] Ensure iron_pickaxe           ← sticks, iron_ingot ×3 (← furnace ← cobblestone
                                                ← wooden/stone pickaxe; iron_ore; fuel)
            [o] Diamond                       mine a visible diamond, else descend to y=12
                                              (A* digs down safely), else tunnel and look

"Ensure X" is ``Selector(Has X?, Sequence(ensure inputs..., act))``: each tick the tree
re-checks from the top (``memory=False`` everywhere), so it resumes from whatever the
inventory holds and repairs itself when things are lost: a log it lacks is fetched
wherever it is (up to the surface from a mine, when a worn-out pickaxe needs sticks).
Every move goes through the
A* travel sub-tree (``leaves.travel``); the grid observation is x-ray, so ores are
chosen from it directly, and no block touching a liquid is ever broken.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Optional

from py_trees.behaviour import Behaviour
from py_trees.composites import Selector, Sequence

from minecraft.agent.corrections import DROP_ITEMS, Corrections
from minecraft.agent.leaves import conditions as C
from minecraft.agent.leaves.context import Context, forget_namespace, share
from minecraft.agent.leaves.goals import (
    Ascend,
    ChooseBlock,
    ChooseDrop,
    Descend,
    Elsewhere,
    Explore,
    MineTarget,
)
from minecraft.agent.leaves.items import Craft
from minecraft.agent.leaves.percept import Percept
from minecraft.agent.leaves.recovery import RECOVER_KEY, EndRecovery, Recovering
from minecraft.agent.leaves.survival import Buried, DigOut, Eat, EscapeLiquid
from minecraft.agent.leaves.travel import travel_subtree
from minecraft.agent.tree_episode import EpisodeResult, TreeEpisode
from minecraft.agent.tree_profile import TimeProfile
from minecraft.malmo.client import MalmoClient

MINING_Y = 12  # feet height for the diamond search: sees y 5..19 in the grid, above lava
REPLAN_TICKS = {"wood": 2400, "elsewhere": 600}  # how long a watchdog re-plan may run
WANTED = DROP_ITEMS
BETTER = {
    "wooden_pickaxe": ("stone_pickaxe", "iron_pickaxe"),
    "stone_pickaxe": ("iron_pickaxe",),
}


class _Builder:
    """Builds the tree's branches in one blackboard namespace."""

    def __init__(self, namespace: str, seed: int) -> None:
        self.ns = namespace
        self.seed = seed

    def has(self, item: str, n: int = 1) -> Behaviour:
        return C.HasItems({item: n}, namespace=self.ns, alternatives=BETTER.get(item, ()))

    def ensure(self, item: str, n: int, steps: list[Behaviour]) -> Behaviour:
        return Selector(
            f"Ensure {item}" + (f" x{n}" if n > 1 else ""),
            memory=False,
            children=[self.has(item, n), Sequence(f"Get {item}", memory=False, children=steps)],
        )

    def craft(self, item: str) -> Behaviour:
        return Craft(item, namespace=self.ns)

    def mine(self, names: tuple[str, ...], *, fallbacks: list[Behaviour]) -> Behaviour:
        """Mine the nearest visible block of ``names``, else run the fallbacks."""
        label = "/".join(names)
        go = Sequence(
            f"Mine {label}",
            memory=False,
            children=[
                ChooseBlock(names, namespace=self.ns),
                travel_subtree(self.ns),
                MineTarget(namespace=self.ns),
            ],
        )
        return Selector(f"Find {label}", memory=False, children=[go, *fallbacks])

    def explore(self, *, level: bool) -> Behaviour:
        return Sequence(
            "Explore",
            memory=False,
            children=[
                Explore(namespace=self.ns, level=level, seed=self.seed),
                travel_subtree(self.ns),
            ],
        )

    def descend(self, y: int) -> Behaviour:
        return Sequence(
            f"Go down to y={y}",
            memory=False,
            children=[
                C.AboveDepth(y, namespace=self.ns),
                Descend(y, namespace=self.ns),
                travel_subtree(self.ns),
            ],
        )

    def log(self) -> Behaviour:
        """A log in the inventory: mine a visible one, else climb to the surface (from
        underground), else explore the surface."""
        up = Sequence(
            "Go up for wood",
            memory=False,
            children=[
                C.Underground(namespace=self.ns),
                Ascend(namespace=self.ns),
                travel_subtree(self.ns),
            ],
        )
        gather = self.mine(("log",), fallbacks=[up, self.explore(level=False)])
        return self.ensure("log", 1, [gather])

    # ----------------------------------------------------------------- needs
    def planks(self, n: int, *, fetch: bool = True) -> Behaviour:
        """``fetch``: get a log when none is held (False: only craft from one held)."""
        log = self.log() if fetch else self.has("log")
        return self.ensure("planks", n, [log, self.craft("planks")])

    def sticks(self, n: int) -> Behaviour:
        return self.ensure("stick", n, [self.planks(2), self.craft("stick")])

    def table(self) -> Behaviour:
        return self.ensure("crafting_table", 1, [self.planks(4), self.craft("crafting_table")])

    def wooden_pickaxe(self) -> Behaviour:
        return self.ensure(
            "wooden_pickaxe",
            1,
            [self.table(), self.sticks(2), self.planks(3), self.craft("wooden_pickaxe")],
        )

    def cobblestone(self, n: int) -> Behaviour:
        dig = self.mine(("stone", "cobblestone"), fallbacks=[self.descend(40)])
        return self.ensure("cobblestone", n, [self.wooden_pickaxe(), dig])

    def stone_pickaxe(self) -> Behaviour:
        return self.ensure(
            "stone_pickaxe",
            1,
            [self.table(), self.sticks(2), self.cobblestone(3), self.craft("stone_pickaxe")],
        )

    def furnace(self) -> Behaviour:
        return self.ensure("furnace", 1, [self.table(), self.cobblestone(8), self.craft("furnace")])

    def iron_ore(self) -> Behaviour:
        dig = self.mine(
            ("iron_ore",),
            fallbacks=[self.descend(MINING_Y), self.explore(level=True)],
        )
        return self.ensure("iron_ore", 1, [self.stone_pickaxe(), dig])

    def fuel(self) -> Behaviour:
        # Coal from coal_ore (common down to y=5) when the wood has run out underground.
        coal = self.mine(("coal_ore",), fallbacks=[self.explore(level=True)])
        planks = self.planks(1, fetch=False)
        return Selector("Fuel", memory=False, children=[self.has("coal"), planks, coal])

    def iron_ingots(self) -> Behaviour:
        return self.ensure(
            "iron_ingot",
            3,
            [self.furnace(), self.iron_ore(), self.fuel(), self.craft("iron_ingot")],
        )

    def iron_pickaxe(self) -> Behaviour:
        # No crafting table asked for here: SimpleCraft crafts anywhere, and smelting may
        # have burnt the table (fuel burns from the first inventory slot up). Sticks are
        # checked after the ingots, since smelting may burn them too.
        return self.ensure(
            "iron_pickaxe", 1, [self.iron_ingots(), self.sticks(2), self.craft("iron_pickaxe")]
        )

    def wood(self) -> Behaviour:
        logs = self.mine(("log",), fallbacks=[self.explore(level=False)])
        return Selector("Wood", memory=False, children=[C.WoodStock(namespace=self.ns), logs])

    def diamond(self) -> Behaviour:
        find = self.mine(
            ("diamond_ore",),
            fallbacks=[self.descend(MINING_Y), self.explore(level=True)],
        )
        return Selector("Diamond", memory=False, children=[self.has("diamond"), find])

    def survive(self) -> Behaviour:
        escape = Sequence(
            "Get out of liquid",
            memory=False,
            children=[C.InLiquid(namespace=self.ns), EscapeLiquid(namespace=self.ns)],
        )
        eat = Sequence(
            "Eat when hungry",
            memory=False,
            children=[C.Hungry(namespace=self.ns), Eat(namespace=self.ns)],
        )
        dig_out = Sequence(
            "Get out of a block",
            memory=False,
            children=[Buried(namespace=self.ns), DigOut(namespace=self.ns)],
        )
        return Selector("Survive", memory=False, children=[escape, dig_out, eat])

    def replan(self) -> Behaviour:
        """The watchdog's re-plans (``agent.watchdog``), each until its aim is reached."""
        away = Sequence(
            "Move away",
            memory=False,
            children=[
                Elsewhere(namespace=self.ns, key=RECOVER_KEY, seed=self.seed),
                travel_subtree(self.ns),
            ],
        )
        plans = {"wood": self.log(), "elsewhere": away}
        return Selector(
            "Re-plan",
            memory=False,
            children=[
                Sequence(
                    f"Re-plan ({plan})",
                    memory=False,
                    children=[
                        Recovering(plan, namespace=self.ns, ticks=REPLAN_TICKS[plan]),
                        node,
                        EndRecovery(namespace=self.ns),
                    ],
                )
                for plan, node in plans.items()
            ],
        )

    def logs(self, n: int) -> Behaviour:
        gather = self.mine(("log",), fallbacks=[self.explore(level=False)])
        return self.ensure("log", n, [gather])

    def root(self, goal: str) -> Behaviour:
        drops = Sequence(
            "Pick up drops",
            memory=False,
            children=[ChooseDrop(WANTED, namespace=self.ns), travel_subtree(self.ns)],
        )
        if goal == "planks":  # a short stage: one log, four planks
            steps = [self.logs(1), self.planks(4)]
        else:
            steps = [self.wood(), self.iron_pickaxe(), self.diamond()]
        quest = Sequence("Quest", memory=False, children=steps)
        return Selector(
            "Obtain diamond",
            memory=False,
            children=[self.survive(), self.replan(), drops, quest],
        )


GOALS = ("diamond", "planks")


def build_tree(
    *, namespace: Optional[str] = None, seed: int = 0, goal: str = "diamond"
) -> tuple[Behaviour, Context]:
    """The obtain-diamond tree and its context (already on the blackboard).

    Args:
        namespace: blackboard namespace (a fresh one by default).
        seed: seeds the exploration headings.
        goal: "diamond" (the whole quest) or "planks" (gather a log, craft planks: the
            same leaves and survival/pick-up branches, for short integration runs).

    Raises:
        ValueError: an unknown goal.
    """
    if goal not in GOALS:
        raise ValueError(f"goal must be one of {GOALS}, got {goal!r}")
    ctx = Context()
    ns = share(ctx, name="diamond_tree", namespace=namespace)
    return _Builder(ns, seed).root(goal), ctx


def run_episode(
    client: MalmoClient,
    *,
    seed: int,
    max_ticks: int = 24_000,
    namespace: Optional[str] = None,
    goal: str = "diamond",
    stop_when: Optional[Callable[[Percept], bool]] = None,
    profile: Optional[TimeProfile] = None,
    ticks_per_step: int = 1,
    corrections: Optional[Corrections] = None,
) -> EpisodeResult:
    """Run the tree in the client's (already initialised) mission until it ends.

    Each step: parse the observation into the context, tick the tree, send the commands
    it wrote (``tree_episode.TreeEpisode``). Nothing but MalmoEnv steps reaches the world.

    Args:
        client: a client with the mission set (``init``); reset here.
        seed: the world seed (for the record and the exploration headings).
        max_ticks: game ticks before giving up (the mission's own time limit ends it too).
        namespace: blackboard namespace.
        goal: see ``build_tree``.
        stop_when: end early when this returns True for a percept.
        profile: charged each tick with the leaf that was running when the action was
            sent (``tree.tip()`` after the tick); its ticks sum to the result's.
        ticks_per_step: ticks each decision is held (a slow client; 1: every tick).
        corrections: learned corrections at the leaves they were trained for.
    """
    root, ctx = build_tree(namespace=namespace, seed=seed, goal=goal)
    episode = TreeEpisode(
        client, root, ctx, seed=seed, max_ticks=max_ticks, stop_when=stop_when,
        profile=profile, ticks_per_step=ticks_per_step, corrections=corrections,
    )  # fmt: skip
    try:
        return episode.run()
    finally:
        forget_namespace(ctx.namespace)
