"""The step's data and blocks of it: the bottom layer, which every other imports and which imports nothing of dgtd.

Glossary (the same in every module): B seeds, N agents, q features, n observations per step (n = N when every
agent runs its own copy of the chain, n = 1 when all observe one shared trajectory, broadcast against N).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple, Protocol

import numpy as np


def namespace(x):
    """The array library of ``x``: jax.numpy for a JAX array (`dgtd.backends.jax`), else NumPy."""
    if type(x).__module__.startswith("jax"):
        import jax.numpy as jnp

        return jnp
    return np


def added(into, index, values):
    """``into`` with ``values`` added at ``index`` (positions that do not repeat): in place for a NumPy array, a new
    array for a JAX one (whose arrays do not change), so that one definition serves both."""
    if namespace(into) is np:
        into[index] += values
        return into
    return into.at[index].add(values)


class Sample(NamedTuple):
    """One step's data for every seed and agent, as an algorithm's ``update`` reads it.

    - ``phi``, ``phi_next`` (B, n, q): features phi(s_i) and phi(s'_i) of each agent's transition;
    - ``r`` (B, N): each agent's local reward (the paper's r-hat_i, section 3);
    - ``ratio`` (B, n): the importance ratio pi(a|s) / beta(a|s) (1 on-policy);
    - ``gamma``: the discount of the transition, a float or an array (B, n) like ``ratio`` (an episodic task's
      gamma(s, s'), 0 at its terminal states).
    """

    phi: np.ndarray
    phi_next: np.ndarray
    r: np.ndarray
    ratio: np.ndarray
    gamma: float | np.ndarray


class SampleTable(NamedTuple):
    """The rows a block's indices point into, when they are not the model's states: a simulator's or a data file's
    samples, each with its own row. ``phi`` (M, q) features, ``ratio`` (M, 1) importance ratios (the block's ``a``
    is 0), ``continuing`` (M,) the c of gamma(s, s') = gamma c(s) c(s'): 0 at the next state of a transition that
    ended an episode."""

    phi: np.ndarray
    ratio: np.ndarray
    continuing: np.ndarray


class Block(NamedTuple):
    """The samples of T steps for B seeds, as state indices: what every block kernel consumes.

    ``s``, ``a``, ``s_next`` (T, B, n) int64; ``r`` (T, B, N) rewards; ``up`` (T, B, E) bool, the edges up at each
    step, or None for a fixed graph; ``table``: the rows the indices point into (`SampleTable`), or None for the
    model's states (the problem's Phi, ratio table and terminal states).
    """

    s: np.ndarray
    a: np.ndarray
    s_next: np.ndarray
    r: np.ndarray
    up: np.ndarray | None
    table: SampleTable | None = None

    @classmethod
    def empty(cls, seeds: int, observations: int, agents: int, edges: int) -> Block:
        """A block of no steps with the documented dtypes: run through a kernel, it loads or compiles it."""
        s = np.zeros((0, seeds, observations), np.int64)
        return cls(s, s.copy(), s.copy(), np.zeros((0, seeds, agents)), np.zeros((0, seeds, edges), bool))

    def sample(self, t: int, Phi: np.ndarray, ratio: np.ndarray, gamma, continuing: np.ndarray | None = None) -> Sample:
        """Step t as a `Sample`, with the features ``Phi`` (S, q) and the ratio table (S, A) of the problem; with
        ``continuing`` c (S,), each transition's discount is gamma c(s) c(s') (an episodic task's terminals)."""
        s, a, sn = self.s[t], self.a[t], self.s_next[t]
        discount = gamma if continuing is None else gamma * continuing[s] * continuing[sn]
        return Sample(Phi[s], Phi[sn], self.r[t], ratio[s, a], discount)


class Source(Protocol):
    """Where a run's samples come from, for B seeds: a model (`dgtd.sources.model.ModelSource`), a simulator
    (`dgtd.sources.env.EnvSource`, the robots' `dgtd.scenarios.robots.PatrolSource`) or recorded data
    (`dgtd.sources.data.DataSource`). Every source delivers the samples of its steps and the links up at them, as
    `Block`s, and its state, which a checkpoint keeps; `dgtd.sources.check.check_source` checks one.

    - ``start()``: begin the streams (a run calls it once, before the first block);
    - ``next_block(T) -> Block``: the next T steps of every seed: s, a, s' (T, B, n), r (T, B, N), the links up
      ``up`` (T, B, E) over the run's graph's edges (None only where every edge is always up), and ``table``, the
      rows the indices point into, where they are not the model's states;
    - ``get_state()`` / ``set_state(state)``: everything the next blocks depend on, so that a resumed run draws
      exactly the blocks an uninterrupted one would; a source whose state cannot be saved (a simulator's) sets
      ``resumable = False``, and a run that would take checkpoints of it is refused when it starts.

    A seed's blocks depend on its own streams only (not on how many seeds run beside it), and T steps are the same
    whether drawn in one block or several.
    """

    def start(self) -> None: ...

    def next_block(self, T: int) -> Block: ...

    def get_state(self) -> dict: ...

    def set_state(self, state: dict) -> None: ...


@dataclass(eq=False)
class Draws:
    """T steps of a model source that are not drawn yet: a compiled kernel that draws its own samples takes them
    from ``source.streams``' keys where it uses them (nothing is materialised) and hands the trajectories' states
    back with `settle`. The samples are those the source's ``next_block(T)`` would have returned."""

    source: Any  # a `dgtd.sources.model.ModelSource` (a layer above this one)
    T: int

    def settle(self, current: np.ndarray | None) -> None:
        self.source.streams.step += self.T
        if current is not None:
            self.source.current = current


def discount(sample: Sample):
    """The step's discount gamma(s, s'), shaped to multiply (B, n, q) features: (B, n, 1), or (1,) for a float."""
    return namespace(sample.phi).asarray(sample.gamma)[..., None]
