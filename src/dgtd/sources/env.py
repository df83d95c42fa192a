"""Samples from a simulator: a PettingZoo ParallelEnv (each agent's own reward), run under a given policy.

The paper's agents learn from samples and never see a model; PettingZoo's parallel API hands each agent its own
reward, which is exactly the paper's local reward r-hat_i. `EnvSource` runs one copy of the environment per seed
(each episode seeded through ``reset(seed=...)`` from the seed's keyed stream, `dgtd.streams`, so a seed's samples
do not depend on the others) and turns its steps into `dgtd.samples.Block` s whose rows (`SampleTable`) hold the
features of each state, computed in one batch per block:

- the state the value function is defined on is the environment's ``state()`` where it has one, else the agents'
  observations concatenated in the order of ``possible_agents``; all agents observe it (n = 1);
- agent i's reward is its PettingZoo reward, or ``reward_map(rewards) -> (N,)`` where the user gives one;
- episodes end as the field has them end (Sutton and Barto 2018, section 3.4; Pardo et al. 2018): a terminal
  transition (``terminations``) has discount 0, so its TD target is the reward alone; a time-limit end
  (``truncations``) is not terminal, so its target bootstraps from the state reached; either way the next
  transition starts from ``reset``, the environment's restart distribution;
- links: a `dgtd.graphs.random.RandomEdges` network draws its edges up from the seed's keyed stream (the links a
  model's run of the same seed draws), or
  ``positions(env) -> (N, dim)`` with a `dgtd.graphs.proximity.ProximityNetwork` links the agents within its
  radius (the robots' and the particles' case).

The environment packages are an optional extra (``pip install dgtd[envs]``); nothing here imports them.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from dgtd.errors import DgtdInputError, call_user, user_error, user_numbers
from dgtd.samples import Block, SampleTable
from dgtd.sources.gym import PARALLEL_API, api_checked
from dgtd.streams import SIMULATOR, edge_uniforms, entity_seed, seed_key


def random_policy(agent: str, observation, space, rng: np.random.Generator):
    """Uniform over a discrete action space; the policy of ``policy="random"``."""
    if not hasattr(space, "n"):
        raise DgtdInputError(
            f"the random policy needs discrete actions; {agent}'s action space is {space}: give a "
            "policy callable(agent, observation, space, rng) -> action"
        )
    return int(rng.integers(space.n))


def checked_action(policy, agent: str, action, space):
    """``action`` where it lies in ``space`` (a discrete space's: a whole number in its range; a box's: its shape,
    within its bounds, in any float type; any other: its ``contains``), else one line: an env may take an action
    outside its space and run on."""
    from gymnasium import spaces  # (PettingZoo's own dependency: there whenever an env is)

    if isinstance(space, spaces.Discrete):
        whole = isinstance(action, (int, np.integer)) and not isinstance(action, (bool, np.bool_))
        inside = whole and int(space.start) <= int(action) < int(space.start) + int(space.n)
    elif isinstance(space, spaces.Box):
        try:
            x = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            x = None
        inside = x is not None and x.shape == space.shape and bool(np.all((x >= space.low) & (x <= space.high)))
    else:
        inside = bool(space.contains(action))
    if not inside:
        raise DgtdInputError(
            f"the policy {named(policy)} returned {action!r} for {agent}, outside its action space {space}; "
            "return one of the space's actions"
        )
    return action


def named(function) -> str:
    """A user's function as its messages name it: its qualified name (a partial's function's)."""
    function = getattr(function, "func", function)
    return getattr(function, "__qualname__", None) or type(function).__name__


def env_state(env, agents) -> np.ndarray:
    """The state the value function is defined on: ``env.state()``, else the observations concatenated."""
    try:
        state = env.state()
    except (NotImplementedError, AttributeError):
        state = None
    except Exception as e:  # noqa: BLE001  (the user's state() failing: theirs to see)
        raise user_error(f"the env's state() ({type(env).__name__})", e) from e
    name = type(env).__name__
    if state is None:
        obs = env._dgtd_last_obs  # set by `EnvSource` at every reset and step
        missing = [a for a in agents if a not in obs]
        if missing:
            raise DgtdInputError(
                f"the env {name} gave no observation of {missing[0]} (its observations are of "
                f"{', '.join(map(str, list(obs)[:4]))}): its state is its possible_agents' observations, so every "
                "agent it makes must be one of its possible_agents"
            )
        state = np.concatenate(
            [np.ravel(user_numbers(f"the env's observation of {a} ({name})", obs[a])) for a in agents]
        )
    return np.ravel(user_numbers(f"the env's state() ({name})", state))


class EnvSource:
    """Blocks of samples from B copies of a ParallelEnv (see the module's docstring).

    ``make_env()`` returns a fresh ParallelEnv; ``features(states (K, dim)) -> (K, q)``; ``policy(agent,
    observation, space, rng) -> action`` or "random"; ``network``: a RandomEdges over the agents, or None with
    ``positions`` and ``proximity``. ``seed_offset`` separates a reference batch's streams from the run's;
    ``n_features``: the width every batch of features must have, when known; ``name``: the env as errors in the user's
    code name it (default: ``make_env``'s name).
    """

    def __init__(
        self,
        make_env: Callable,
        features: Callable,
        seed: int,
        seed_ids,
        *,
        policy="random",
        network=None,
        positions: Callable | None = None,
        proximity=None,
        reward_map: Callable | None = None,
        seed_offset: int = 0,
        n_features: int | None = None,
        name: str | None = None,
    ):
        self.make_env, self.features, self.n_features = make_env, features, n_features
        self.policy = random_policy if policy == "random" else policy
        self.network, self.positions, self.proximity = network, positions, proximity
        if network is None and (positions is None or proximity is None):
            raise DgtdInputError(
                "give the environment's network: a random-edge network over its agents, or "
                "positions(env) with a proximity network"
            )
        self.reward_map = reward_map
        self.name = name or named(make_env)
        self.seed, self.seed_ids, self.seed_offset = int(seed), [int(k) for k in seed_ids], int(seed_offset)
        self.envs: list = []  # (`start` makes them)
        self.agents: list = []
        self.current: list = []
        self.gens: list = []
        self.spaces: list = []

    @property
    def edges(self) -> np.ndarray:
        return (self.network.base if self.network is not None else self.proximity.base).edges

    def start(self) -> None:
        self.envs, self.gens, self.current, self.spaces = [], [], [], []
        # seed id k's key: its episodes' seeds, its policy's generator and its links are its own (`dgtd.streams`)
        self.keys = [seed_key(self.seed, self.seed_offset + k) for k in self.seed_ids]
        self.episodes, self.step = [0] * len(self.seed_ids), 0
        for b, key in enumerate(self.keys):
            env = call_user(f"{self.name}()", self.make_env)
            gen = np.random.default_rng(entity_seed(key, SIMULATOR, 1))  # the policy's: a user's callable takes one
            for name in ("reset", "step", "possible_agents", "action_space"):
                if not hasattr(env, name):
                    raise DgtdInputError(
                        f"make_env() returned {type(env).__name__}, which has no {name}: give a "
                        "PettingZoo ParallelEnv (pettingzoo.ParallelEnv; wrap an AEC env with "
                        "pettingzoo.utils.aec_to_parallel)"
                    )
            self.envs.append(env)
            self.gens.append(gen)
            self.spaces.append({a: env.action_space(a) for a in env.possible_agents})  # fixed, as PettingZoo asks
            self.current.append(self._reset(env, b))
        self.agents = list(self.envs[0].possible_agents)

    def _reset(self, env, b: int) -> np.ndarray:
        """A new episode of seed b's env, seeded by (its key, simulator, episode)."""
        seed = entity_seed(self.keys[b], SIMULATOR, 0, self.episodes[b]) % (2**31 - 1)
        self.episodes[b] += 1
        what = f"the env's reset() ({self.name})"
        obs, _ = api_checked(call_user(what, env.reset, seed=seed), 2, what, PARALLEL_API)
        env._dgtd_last_obs = obs
        return env_state(env, list(env.possible_agents))

    def next_block(self, T: int) -> Block:
        B, N = len(self.envs), len(self.agents)
        E = len(self.edges)
        states, nexts = np.empty((T, B), dtype=object), np.empty((T, B), dtype=object)
        r = np.empty((T, B, N))
        cont_next = np.ones((T, B))
        up = np.empty((T, B, E), bool)
        for b, (env, gen, spaces) in enumerate(zip(self.envs, self.gens, self.spaces)):
            if self.positions is None:  # the links' draws do not depend on the env: all T steps at once
                steps = (self.step + np.arange(T, dtype=np.uint64))[:, None]
                up[:, b] = edge_uniforms(self.keys[b : b + 1], steps[:, :, None], self.edges)[:, 0] < self.network.p
            for t in range(T):
                obs = env._dgtd_last_obs
                actions = {
                    a: checked_action(
                        self.policy,
                        a,
                        call_user(f"the policy {named(self.policy)}", self.policy, a, obs[a], spaces[a], gen),
                        spaces[a],
                    )
                    for a in env.agents
                }
                if self.positions is not None:
                    up[t, b] = self.proximity.masks(self._positions(env))
                states[t, b], r[t, b], nexts[t, b], cont_next[t, b] = self.act(b, actions)
        self.step += T
        M = T * B
        phi = self.features_of(list(states.ravel()) + list(nexts.ravel()))
        index = np.arange(M).reshape(T, B, 1)
        table = SampleTable(phi, np.ones((2 * M, 1)), np.concatenate([np.ones(M), cont_next.ravel()]))
        return Block(index, np.zeros_like(index), index + M, r, up, table)

    def observations(self, b: int) -> dict:
        """Seed b's env's newest observations, agent -> observation."""
        return self.envs[b]._dgtd_last_obs

    def act(self, b: int, actions: dict) -> tuple:
        """One step of seed b's env with ``actions`` (agent -> action): (the state, every agent's reward (N,), the
        state reached, 0.0 where it is terminal else 1.0); a finished episode is followed by a new one."""
        env = self.envs[b]
        what = f"the env's step() ({self.name})"
        obs, rewards, terms, truncs, _ = api_checked(call_user(what, env.step, actions), 5, what, PARALLEL_API)
        env._dgtd_last_obs = obs
        state, r, reached = self.current[b], self._rewards(rewards, actions), env_state(env, self.agents)
        terminated = any(terms.get(a, False) for a in self.agents)  # a terminal transition's target: its reward
        if terminated or not env.agents or any(truncs.get(a, False) for a in self.agents):
            self.current[b] = self._reset(env, b)
        else:
            self.current[b] = reached
        return state, r, reached, 0.0 if terminated else 1.0

    def features_of(self, states: list) -> np.ndarray:
        """The features (K, q) of states (K of one shape), each checked: finite, of the width every batch has."""
        try:
            rows = np.stack(states)
        except ValueError:
            raise DgtdInputError(
                "the environment's states change size from step to step; its state() (or its "
                "observations) must have one shape"
            ) from None
        if not np.isfinite(rows).all():
            raise DgtdInputError(
                "the environment returned NaN or infinite states (its state() or observations); "
                "check the env, or wrap it to clip them"
            )
        what = f"the features {named(self.features)}"
        phi = user_numbers(what, call_user(what, self.features, rows))
        if self.n_features is not None and phi.ndim == 2 and phi.shape[1] != self.n_features:
            raise DgtdInputError(
                f"the features came out {phi.shape[1]} wide, not {self.n_features} as on the first "
                "states; features(states) must return the same number of columns for every batch"
            )
        if phi.ndim != 2 or phi.shape[0] != len(rows) or not phi.shape[1] or not np.isfinite(phi).all():
            raise DgtdInputError(
                f"the features of {len(rows)} states came out with shape {np.shape(phi)}"
                f"{'' if np.isfinite(phi).all() else ' and NaN or infinite entries'}; features(states "
                "(K, dim)) must return finite (K, q), q >= 1"
            )
        return phi

    def _rewards(self, rewards, acted) -> np.ndarray:
        """Each agent's reward of a step, checked: every agent that acted has one, and each is a number. An agent
        that did not act at the step (not among the env's live agents) earns 0."""
        if not isinstance(rewards, dict):
            raise DgtdInputError(
                f"the env's step() ({self.name}) returned rewards of type {type(rewards).__name__}, "
                "not a dict of each agent's reward"
            )
        if self.reward_map is not None:
            r = call_user(f"the reward map {named(self.reward_map)}", self.reward_map, rewards)
        else:
            missing = [a for a in acted if a not in rewards]
            if missing:
                raise DgtdInputError(
                    f"the env's step() ({self.name}) gave no reward for "
                    f"{', '.join(map(str, missing))}, which acted at that step: every live agent "
                    "needs its reward (0 is a reward)"
                )
            unknown = [a for a in rewards if a not in self.agents]
            if unknown:
                raise DgtdInputError(
                    f"the env's step() ({self.name}) gave a reward for "
                    f"{', '.join(map(str, unknown))}, not among its possible_agents "
                    f"({', '.join(map(str, self.agents))})"
                )
            r = []
            for a in self.agents:
                value = rewards.get(a, 0.0)
                try:
                    r.append(float(value))
                except (TypeError, ValueError):
                    raise DgtdInputError(
                        f"the env's step() ({self.name}) gave {a} the reward {value!r}, which is not a number"
                    ) from None
        try:
            r = np.asarray(r, dtype=np.float64)
        except (TypeError, ValueError):
            raise DgtdInputError(
                f"the step's rewards came out as {r!r}; each of the {len(self.agents)} agents needs a finite number"
            ) from None
        if r.shape != (len(self.agents),) or not np.isfinite(r).all():
            raise DgtdInputError(
                f"the step's rewards came out as {r!r}; each of the {len(self.agents)} agents needs a finite reward"
            )
        return r

    def _positions(self, env) -> np.ndarray:
        """The agents' positions (N, dim) from the user's positions(env), checked: one finite row per agent."""
        what = f"positions {named(self.positions)}"
        where = user_numbers(what, call_user(what, self.positions, env))
        n = self.proximity.n_nodes
        if where.ndim != 2 or where.shape[0] != n:
            raise DgtdInputError(
                f"{what} must return the positions of {n} agents, one row each: got shape {where.shape}"
            )
        if not np.isfinite(where).all():
            raise DgtdInputError(f"{what} returned NaN or infinite positions: no link could be measured from them")
        return where

    resumable = False  # a simulator's state cannot be saved: runs on environments take no checkpoints

    def get_state(self) -> dict:
        return {}

    def set_state(self, state: dict) -> None:
        raise DgtdInputError("a run on an environment cannot be resumed from a checkpoint; run it again")


def reference_from_env(
    make_source: Callable, n_features: int, gamma: float, name: str, steps: int, groups: int = 8, block: int = 2048
):
    """(the LSTD reference, how often each link was up): `dgtd.problems.reference.estimate` from ``groups``
    independent sources of ``steps`` steps each; ``make_source(group)`` returns a fresh `EnvSource` whose streams are
    separate from the run's. The link frequencies give the mean graph of a proximity network."""
    from dgtd.problems.reference import MomentSums, TDCheck, estimate

    sums, up, count, td = [], 0.0, 0, TDCheck(n_features)
    for g in range(int(groups)):
        source = make_source(g)
        source.start()
        acc = MomentSums(len(source.agents), n_features)
        done = 0
        while done < steps:
            T = min(block, steps - done)
            blk = source.next_block(T)
            tab = blk.table
            s, sn = blk.s.ravel(), blk.s_next.ravel()
            r = blk.r.reshape(-1, blk.r.shape[-1])
            discount = gamma * tab.continuing[s] * tab.continuing[sn]
            acc.add(tab.phi[s], tab.phi[sn], r, discount, tab.ratio[s, 0])
            td.add(tab.phi[s], tab.phi[sn], r.mean(axis=1), discount, tab.ratio[s, 0])
            up, count = up + blk.up.sum(axis=(0, 1)), count + blk.up.shape[0] * blk.up.shape[1]
            done += T
        sums.append(acc)
    return estimate(name, gamma, sums, td_check=td), up / max(count, 1)
