"""One episode of the obtain-diamond tree over the Malmo protocol, a step at a time, with
the learned corrections (``corrections``) acting where they were trained.

Each step: parse the observation into the context; (drops correction) decide on every
wanted item newly in reach; tick the tree; (travel correction) replace the walking
commands; send them, and hold them for ``ticks_per_step`` ticks (a slow client: Malmo's
continuous commands persist, the frames between are unseen). ``run_episode`` loops
it; ``drop_env`` pauses it at each drop decision.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Optional

import numpy as np
import py_trees
from py_trees.behaviour import Behaviour

from minecraft.agent.corrections import (
    DROP_ACTIONS,
    SKIPPED_KEY,
    Corrections,
    TravelCorrection,
    drop_observation,
    new_drops,
)
from minecraft.agent.leaves.context import Context
from minecraft.agent.leaves.percept import ItemSeen, Percept, parse
from minecraft.agent.tree_profile import TimeProfile
from minecraft.agent.watchdog import Watchdog
from minecraft.malmo.client import MalmoClient, StepResult

MILESTONES = (
    "log", "planks", "stick", "crafting_table", "wooden_pickaxe", "cobblestone",
    "stone_pickaxe", "iron_ore", "furnace", "iron_ingot", "iron_pickaxe", "diamond",
)  # fmt: skip


@dataclass
class EpisodeResult:
    """One run of the tree in one world.

    Attributes:
        seed: world seed.
        diamond: a diamond was obtained.
        stage: the furthest milestone item ever held.
        ticks: game ticks used (20 per second).
        deaths: 1 if the agent died (death ends a Malmo mission).
        end: why the episode ended.
        stuck: times the agent was jammed in one cell while travelling.
        reached: milestone -> tick it was first held.
        drops_left: wanted items a drops correction chose to leave.
        drops_decided: wanted items a drops correction decided on.
        watchdog: times the watchdog fired (no progress: a re-plan).
    """

    seed: int
    diamond: bool
    stage: str
    ticks: int
    deaths: int
    end: str
    stuck: int = 0
    reached: dict[str, int] = field(default_factory=dict)
    drops_left: int = 0
    drops_decided: int = 0
    watchdog: int = 0


class TreeEpisode:
    """The tree ``root`` (with its context ``ctx``) run in the client's mission.

    Args:
        client: a client with the mission set (``init``); reset by ``start``.
        root, ctx: the tree and its context (``diamond_tree.build_tree``).
        seed: the world seed (for the record).
        max_ticks: game ticks before giving up (the mission's own time limit ends it too).
        stop_when: end early when this returns True for a percept.
        profile: charged each tick with the leaf that was running when the action was
            sent (``tree.tip()`` after the tick); its ticks sum to the result's.
        ticks_per_step: ticks each decision's commands are held (1: every tick).
        corrections: learned corrections in place (empty: the tree alone).
        gate_drops: stop at each new wanted item in reach (``pending_drop``) for the
            caller to ``decide``, without a drops policy (the drops environment).
        watchdog: checked after every tick (``watchdog.Watchdog``; the default one
            unless given); its firings are counted in the profile.
    """

    def __init__(
        self,
        client: MalmoClient,
        root: Behaviour,
        ctx: Context,
        *,
        seed: int,
        max_ticks: int = 24_000,
        stop_when: Optional[Callable[[Percept], bool]] = None,
        profile: Optional[TimeProfile] = None,
        ticks_per_step: int = 1,
        corrections: Optional[Corrections] = None,
        gate_drops: bool = False,
        watchdog: Optional[Watchdog] = None,
    ) -> None:
        if ticks_per_step < 1:
            raise ValueError(f"ticks_per_step={ticks_per_step} must be >= 1")
        self.client, self.ctx, self.seed = client, ctx, seed
        self.tree = py_trees.trees.BehaviourTree(root)
        self.max_ticks, self.stop_when, self.profile = max_ticks, stop_when, profile
        self.k = ticks_per_step
        ctx.commands.hold = ticks_per_step  # the leaves' controllers size commands to it
        self.corrections = corrections or Corrections()
        self.gate_drops = gate_drops or self.corrections.drops is not None
        travel, where = self.corrections.travel, self.corrections.travel_activities
        self.travel = TravelCorrection(travel, where) if travel else None
        self.decided: dict[str, int] = {}
        self.last_choice = ""  # the last drop decision, for captions ("leave cobblestone")
        self.last_choice_tick = -1
        self.reply: Optional[StepResult] = None
        self.best, self.ticks, self.steps, self.end = -1, 0, 0, "time limit"
        self.reached: dict[str, int] = {}
        self._elapsed = 1
        self.watchdog = watchdog or Watchdog()

    def start(self) -> bool:
        """Reset the mission and read the first observation; False if it already ended."""
        self.client.reset()
        self.reply = self.client.step("")
        return self.observe()

    def observe(self) -> bool:
        """Parse the latest reply into the context; False when the episode is over."""
        reply, ctx = self.reply, self.ctx
        assert reply is not None
        tick_before = ctx.percept.tick
        ctx.percept = parse(reply.info)
        self._elapsed = max(1, ctx.percept.tick - tick_before)
        self.ticks = ctx.percept.tick
        if self.profile is not None:
            self.profile.observed(ctx.percept)
        for i, m in enumerate(MILESTONES):
            if m not in self.reached and ctx.percept.count(m):
                self.reached[m] = self.ticks
                self.best = max(self.best, i)
        if reply.done:
            self.end = "done"
            return False
        if self.stop_when is not None and self.stop_when(ctx.percept):
            self.end = "stopped"
            return False
        return self.steps * self.k < self.max_ticks

    def pending_drop(self) -> Optional[ItemSeen]:
        """The nearest wanted item in reach not decided on yet (None when drops are not
        gated: the tree chases every one)."""
        if not self.gate_drops:
            return None
        found = new_drops(self.ctx.percept, self.decided)
        return found[0] if found else None

    def drop_state(self, item: ItemSeen) -> np.ndarray:
        """The drops correction's observation of ``item``."""
        return drop_observation(self.ctx.percept, item)

    def decide(self, item: ItemSeen, action: int) -> None:
        """Chase (0) or leave (1) ``item``."""
        self.decided[item.uid] = int(action)
        self.last_choice = f"{DROP_ACTIONS[int(action)]} {item.name}"
        self.last_choice_tick = self.ticks
        if action:
            self.ctx.memory.setdefault(SKIPPED_KEY, set()).add(item.uid)

    def act(self) -> None:
        """Tick the tree, apply the travel correction, send the step and hold it."""
        ctx, client = self.ctx, self.client
        if self.corrections.drops is not None:
            while (item := self.pending_drop()) is not None:
                self.decide(item, int(np.asarray(self.corrections.drops(self.drop_state(item)))))
        ctx.commands.still()
        ctx.commands.once = []
        self.tree.tick()
        tip = self.tree.tip()
        if self.travel is not None:
            self.travel.apply(tip, ctx, self._elapsed)
        if self.profile is not None:
            self.profile.acted(tip, ctx)
        if self.watchdog.check(ctx) is not None and self.profile is not None:
            self.profile.fired()
        reply = client.step(ctx.commands.render())
        for _ in range(self.k - 1):
            if reply.done or not reply.info:
                break
            reply = client.step("")
        self.reply = reply
        self.steps += 1

    def run(self) -> EpisodeResult:
        """Play the episode to its end."""
        alive = self.start()
        while alive:
            self.act()
            alive = self.observe()
        return self.result()

    def correction_note(self, *, hold: int = 40) -> str:
        """What the corrections did at the last step, in a few words (for captions): the
        travel correction π(s) = a − μ(s) while walking, a drop decision for ``hold``
        ticks after it was taken; "" when neither."""
        if self.travel is not None and self.travel.last is not None:
            d = self.travel.last
            return f"RL walk: move {d[0]:+.2f} strafe {d[1]:+.2f} turn {d[2]:+.2f}"
        if self.last_choice and self.ticks - self.last_choice_tick <= hold:
            return f"RL drops: {self.last_choice}"
        return ""

    def result(self) -> EpisodeResult:
        """The outcome, once ``observe`` returned False."""
        reply, ctx, best = self.reply, self.ctx, self.best
        assert reply is not None
        final = parse(reply.info) if reply.info else ctx.percept
        got = final.count("diamond") > 0 or (reply.done and best == len(MILESTONES) - 1)
        end = "died" if reply.done and reply.info and not final.alive else self.end
        deaths = 1 if end == "died" or (reply.done and not got and final.life <= 0) else 0
        for i, m in enumerate(MILESTONES):
            if i > best and final.count(m):
                best = i
        ticks = max(self.ticks, final.tick)
        if self.profile is not None:
            self.profile.finish(ticks)
        return EpisodeResult(
            seed=self.seed,
            diamond=got or best == len(MILESTONES) - 1,
            stage=MILESTONES[best] if best >= 0 else "none",
            ticks=ticks,
            deaths=deaths,
            end=end,
            stuck=int(ctx.memory.get("stuck_total", 0)),
            reached=self.reached,
            drops_left=sum(self.decided.values()),
            drops_decided=len(self.decided),
            watchdog=self.watchdog.firings,
        )
