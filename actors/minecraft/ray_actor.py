"""A Ray actor per Minecraft client: it drives one world server (a real Malmo Minecraft or
graft's simulator) in real time and streams transitions to the replay server.

The loop ``run()`` executes, one iteration per world observation::

    obs = encode(reset())                               # reconnects with backoff
    while running:
        adopt new weights if the learner published some  # WeightSubscriber.poll(), no wait
        action, log_prob, version = behaviour.act(obs)   # unclipped action, its density
        reply = client.step(commands(clip(action)))     # waits for the next world tick
        next_obs = encode(reply.info)
        meter.observe(reply.info["TotalTime"], own_time) # ticks skipped, step latency
        writer.add(obs, action, reward, terminated, truncated, next_obs, log_prob, version)
        obs = next_obs (or a new episode)

Nothing in it waits for the learner: weights are polled, inserts go out from a
background thread (``TransitionWriter``). Malmo's semantics set the transition's
timing: a step's reply shows the world *before* that step's commands ran (they apply
at the next tick), as in ``malmoenv``; continuous commands persist, so the effect of an
action shows one observation later.

``own_time`` (the reported step latency) is the time between an observation arriving
and the next command leaving: encoding, acting, bookkeeping, and in the naive loop the
training. When it exceeds ``MsPerTick`` the world ticks unobserved (skipped ticks).
"""

from __future__ import annotations

import os
import threading
import time
from typing import Any, Optional

import numpy as np
import ray
import torch

from actors.minecraft.behaviour import MinecraftBehaviour
from actors.minecraft.encoding import action_commands, encode_observation, observation_space
from actors.minecraft.inline import InlineTrainer
from actors.minecraft.malmo import protocol as P
from actors.minecraft.malmo.client import MalmoClient, StepResult
from actors.minecraft.malmo.mission import Mission, parse_mission
from actors.minecraft.metrics import TickMeter
from actors.minecraft.writer import TransitionWriter
from learner.td3.config import TD3Config
from service.replay.client import ReplayClient
from service.weights import WeightSubscriber

# What a world server going away looks like from the client (refused, reset, closed, hung).
_LOST = (OSError, P.ProtocolError)


class MinecraftAgent:
    """One Minecraft client's acting loop (wrapped as the Ray actor ``MinecraftActor``).

    Args:
        host: world server address.
        port: world server port.
        mission_xml: the mission to run (needs ObservationFromFullStats).
        td3: network architecture and exploration noise of the behaviour policy.
        seed: seeds exploration (and the naive loop's learner).
        replay: replay server client, or None to keep no transitions (naive loop).
        table: replay table to insert into.
        broadcaster: the learner's ``WeightBroadcaster``, or None (act at random, or
            with the naive loop's own network).
        synchronous: MineRL's synchronous mode (one tick per step); real time if False.
        world_seed: ask the (graft) server for this world seed; None for real Malmo.
        insert_every: transitions per replay insert.
        max_episode_steps: steps after which the actor truncates the episode itself.
        inline_updates_per_step: > 0 selects the paper's naive loop: this many TD3
            updates on the actor's own buffer after every step, inside the acting loop.
        inline_learning_starts: the naive loop's buffer size before its first update.
        max_backoff_s: longest pause between reconnection attempts.
        nice: CPU niceness of the acting thread, or None to leave it. Ray starts workers
            at nice 15 (``RAY_worker_niceness``), below every ordinary process, so a busy
            machine would starve a real-time client; 0 asks for an ordinary share.
            Lowering niceness needs CAP_SYS_NICE or RLIMIT_NICE: without it the actor
            keeps its niceness and reports it (``actor/nice``).
    """

    def __init__(
        self,
        *,
        host: str,
        port: int,
        mission_xml: str,
        td3: TD3Config,
        seed: int,
        replay: Optional[ReplayClient] = None,
        table: str = "transitions",
        broadcaster: Any = None,
        synchronous: bool = False,
        world_seed: Optional[int] = None,
        insert_every: int = 32,
        max_episode_steps: Optional[int] = None,
        inline_updates_per_step: int = 0,
        inline_learning_starts: int = 256,
        max_backoff_s: float = 5.0,
        nice: Optional[int] = 0,
    ) -> None:
        torch.set_num_threads(1)
        self.mission: Mission = parse_mission(mission_xml)
        obs_dim = observation_space(self.mission).shape[0]
        self.client = MalmoClient(
            host, port, synchronous=synchronous, seed=world_seed, timeout=10.0, connect_attempts=1
        )
        self.client.init(mission_xml)
        self.rng = np.random.default_rng(seed)
        self.behaviour = MinecraftBehaviour(obs_dim, td3)
        self.weights = WeightSubscriber(broadcaster) if broadcaster is not None else None
        self.writer = (
            TransitionWriter(replay, table, insert_every=insert_every)
            if replay is not None
            else None
        )
        self.trainer = (
            InlineTrainer(
                obs_dim,
                td3=td3,
                seed=seed,
                updates_per_step=inline_updates_per_step,
                learning_starts=inline_learning_starts,
            )
            if inline_updates_per_step > 0
            else None
        )
        self.max_episode_steps = max_episode_steps
        self.max_backoff_s = max_backoff_s
        self.nice = nice
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)
        self.address = f"{host}:{port}"
        self.meter = TickMeter()
        self._stop = threading.Event()
        self._obs: Optional[np.ndarray] = None
        self._episode_steps = 0
        self._backoff = 0.05
        self._t_ready = 0.0
        self._last_total = 0
        self._lost_since_reconnect = False
        self.steps = self.episodes = 0
        self.connection_losses = self.reconnects = 0
        self.last_error = ""
        self.versions_adopted: list[int] = []
        self._measure_start = time.monotonic()
        self._measure_steps = 0
        self._step_call_s = 0.0

    # ------------------------------------------------------------------ control
    def stop(self) -> None:
        """Ask a running ``run()`` to return after its current step."""
        self._stop.set()

    def reset_meters(self) -> None:
        """Start a new measurement window (ticks skipped, latency, rates)."""
        self.meter = TickMeter()
        self._measure_start = time.monotonic()
        self._measure_steps = 0
        self._step_call_s = 0.0

    def run(
        self,
        *,
        duration_s: Optional[float] = None,
        max_steps: Optional[int] = None,
        measure_after_s: float = 0.0,
    ) -> dict[str, Any]:
        """Act until ``duration_s`` passed, ``max_steps`` steps were taken, ``stop()``
        was called or the learner stopped the broadcast; then flush and report.

        Args:
            duration_s: wall-clock budget in seconds.
            max_steps: step budget.
            measure_after_s: reset the meters this long after starting (a warm-up).

        Raises:
            ValueError: neither budget was given (the loop would never end).
        """
        if duration_s is None and max_steps is None:
            raise ValueError("give duration_s or max_steps: run() would never return")
        self._stop.clear()
        self._set_priority()
        start = time.monotonic()
        deadline = start + duration_s if duration_s is not None else float("inf")
        last_step = self.steps + max_steps if max_steps is not None else None
        warming = measure_after_s > 0
        self.reset_meters()
        while not self._stop.is_set() and time.monotonic() < deadline:
            if last_step is not None and self.steps >= last_step:
                break
            if self.weights is not None and self.weights.stopped:
                break
            if warming and time.monotonic() - start >= measure_after_s:
                self.reset_meters()
                warming = False
            if self._obs is None:
                self._begin_episode(deadline)
                continue
            self._step()
        if self.writer is not None:
            self.writer.flush()
        return self.report()

    def _set_priority(self) -> None:
        # Linux niceness is per thread: set it on the thread that runs the loop.
        if self.nice is not None:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, self.nice)
            except OSError as e:
                self.last_error = f"cannot set nice {self.nice}: {e}"
        self.acting_nice = os.getpriority(os.PRIO_PROCESS, 0)

    # ------------------------------------------------------------------ episode
    def _begin_episode(self, deadline: float) -> None:
        """Reset (reconnecting if needed) and read the first observation; on failure
        sleep with exponential backoff and return (the loop tries again)."""
        try:
            self.client.reset()
            first = self.client.observe()  # real Malmo may answer a step without info
            if first.done or not first.info:
                raise P.ProtocolError("the new mission ended before its first observation")
        except _LOST as e:
            self.last_error = f"{type(e).__name__}: {e}"
            self.client.close()
            time.sleep(max(0.0, min(self._backoff, deadline - time.monotonic())))
            self._backoff = min(self._backoff * 2, self.max_backoff_s)
            return
        self._backoff = 0.05
        if self._lost_since_reconnect:
            self.reconnects += 1
            self._lost_since_reconnect = False
        self._obs = encode_observation(first.info, self.mission)
        self._episode_steps = 0
        self.meter.reset_episode()
        self._last_total = int(first.info["TotalTime"])
        self.meter.observe(self._last_total)
        self._t_ready = time.perf_counter()

    def _lose_connection(self, error: BaseException) -> None:
        self.connection_losses += 1
        self._lost_since_reconnect = True
        self.last_error = f"{type(error).__name__}: {error}"
        self.client.close()
        self._obs = None  # the unfinished step is not recorded: it has no next observation

    def _poll_weights(self) -> None:
        if self.weights is None:
            return
        weights = self.weights.poll()
        if weights is not None:
            self.behaviour.load(weights, self.weights.version)
            self.versions_adopted.append(self.weights.version)

    def _step(self) -> None:
        assert self._obs is not None
        self._poll_weights()
        action, log_prob, version = self.behaviour.act(self._obs, self.rng)
        commands = action_commands(action)
        t_send = time.perf_counter()
        own_s = t_send - self._t_ready
        try:
            reply = self.client.step(commands)
        except _LOST as e:
            self._lose_connection(e)
            return
        self._t_ready = time.perf_counter()
        self._step_call_s += self._t_ready - t_send
        self.steps += 1
        self._measure_steps += 1
        self._episode_steps += 1
        if reply.info:
            next_obs = encode_observation(reply.info, self.mission)
            self._last_total = int(reply.info["TotalTime"])
            self.meter.observe(self._last_total, own_s)
        else:  # the mission ended between ticks: no newer observation exists
            next_obs = self._obs
        terminated, truncated = self._ending(reply)
        record = {
            "obs": self._obs,
            "action": action.astype(np.float32),
            "reward": np.float32(reply.reward),
            "terminated": np.bool_(terminated),
            "truncated": np.bool_(truncated),
            "next_obs": next_obs,
            "log_prob": np.float32(log_prob),
            "policy_version": np.int64(version),
        }
        if self.writer is not None:
            self.writer.add(record)
        if self.trainer is not None:
            self.trainer.add(record)
            if self.trainer.train():  # the naive loop: training inside the acting loop
                self.behaviour.follow(self.trainer.learner.actor, self.trainer.num_updates)
        if terminated or truncated:
            self.episodes += 1
            self._obs = None
        else:
            self._obs = next_obs

    def _ending(self, reply: StepResult) -> tuple[bool, bool]:
        """(terminated, truncated): death or a mission goal terminates; the mission's
        time limit or the actor's step limit truncates (truncation is not termination:
        the learner still bootstraps through it)."""
        if not reply.done:
            limit = self.max_episode_steps
            return False, limit is not None and self._episode_steps >= limit
        info = reply.info
        if info and not info.get("IsAlive", True):
            return True, False  # died
        total = int(info["TotalTime"]) if info else self._last_total + 1
        limit_ms = self.mission.time_limit_ms
        if limit_ms is not None and total * 50 >= limit_ms:
            return False, True  # ServerQuitFromTimeUp (game time is 50 ms a tick)
        return True, False  # an AgentQuitFrom... goal, or the agent quit

    # ------------------------------------------------------------------ report
    def report(self) -> dict[str, Any]:
        """Namespaced counters and rates of the current measurement window."""
        wall = max(time.monotonic() - self._measure_start, 1e-9)
        m = self.meter
        out: dict[str, Any] = {
            "actor/address": self.address,
            "actor/steps": self.steps,
            "actor/episodes": self.episodes,
            "actor/nice": self.acting_nice,
            "perf/steps_per_s": self._measure_steps / wall,
            "perf/world_ticks_per_s": (m.seen + m.skipped) / wall,
            "perf/ticks_seen": m.seen,
            "perf/step_call_ms_mean": 1000.0 * self._step_call_s / max(self._measure_steps, 1),
            "perf/measure_s": wall,
            "net/connection_losses": self.connection_losses,
            "net/reconnects": self.reconnects,
            "net/last_error": self.last_error,
            "policy/version": self.behaviour.version,
            "policy/versions_adopted": len(self.versions_adopted),
        }
        out.update(m.metrics())
        if self.writer is not None:
            out["replay/inserted"] = self.writer.inserted
            out["replay/dropped"] = self.writer.dropped
            out["replay/errors"] = self.writer.errors
            out["replay/insert_s"] = self.writer.insert_s
        if self.trainer is not None:
            out["learner/inline_updates"] = self.trainer.num_updates
        return out

    def close(self) -> None:
        """Flush the writer and release the world server."""
        if self.writer is not None:
            self.writer.close()
        self.client.close()


# Two concurrent calls: `report()` / `stop()` answer while `run()` is acting.
MinecraftActor = ray.remote(num_cpus=0.25, max_concurrency=2)(MinecraftAgent)
