"""Agents that improve their policies: the networked actor-critic of Zhang, Yang, Liu, Zhang and Basar (ICML 2018,
Algorithm 2: a state-value critic and a consensus estimate of the team's reward), with any of dgtd's distributed
critics over the same links as `dgtd run`. One loop runs a model and a simulator, each behind the protocol of
`dgtd.sources.team_env` (what the actors see, a step's features and rewards), with the arithmetic of
`dgtd.algorithms.actor` and `dgtd.algorithms.team_reward` (the compiled kernels run the same definitions).

One step k, for B seeds at once (agents and seeds are array axes; every random number keyed, `dgtd.streams`):

    draw      each agent's action a_i ~ pi_i(. | s) (purpose ACTION, entity i), the next state s' ~ P(s, a, .)
              (SHARED_STATE; a simulator's own step), the links up (EDGE_UP), as `dgtd run` draws a shared
              trajectory's;
    hear      the channel delivers what every agent sends: its critic's messages, and for networked actors its
              estimate of the team's reward (`dgtd.channels`: lost, late or compressed as asked, counted);
    advantage delta_i = rhat_i - mu~_i + Phi(s') w_i - Phi(s) w_i (`td_error`), with rhat_i the team's reward as
              agent i knows it: networked, its consensus estimate lambda_i^T f(s, a) (Zhang et al.'s Algorithm 2);
              independent, its own r_i; centralised, the true team reward rbar (a ceiling no network gives); mu~_i
              its running average of rhat_i (the average objective's differential TD error; discounted: gamma
              Phi(s') w_i and no mu~_i, `objective_terms`);
    critic    the chosen distributed method's update (`algorithm.update`, the paper's Algorithm 1 for DGTD) on each
              agent's own reward less its running average mu_i, undiscounted (centralised: on rbar; discounted: the
              reward itself at gamma), alpha_k its schedule; independent agents hear no one;
    reward    networked: lambda_i <- lambda_i - sum_j W_ij (lambda_i - lambda_j) + nu_k (r_i - rhat_i) f(s, a)
              (Metropolis mixing over the links up, then a regression step on the agent's own reward: the
              consensus of the regressions of r_i is the regression of rbar);
    actor     theta_i <- theta_i + beta_k delta_i psi_i (`dgtd.algorithms.actor`), beta_k = 0 for the warm-up's
              steps, then beta_k / alpha_k -> 0.

f(s, a) is additive over the agents, f = (g(s) e_{a_1}^T, ..., g(s) e_{a_N}^T) with g(s) = e_s on a model (N A_max S
numbers, N of them ones): it represents any team reward that is a sum of per-agent terms exactly (the pull-away
task's is); in a simulator g(s) = phi(s), the critics' features. At every checkpoint on a model the exact return
J(pi_t) of the current policies under the run's objective (`dgtd.problems.team.objective_return`), the critics' error
against the exact critic of pi_t (Chen, Zhou, Chen and Zou 2022: ||W - W*(pi_t)||^2 / (N ||W*||^2)) and the
policies' entropy are recorded (`dgtd.problems.team`); in a simulator, estimates from the run's own rewards
(`_record`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from dgtd.algorithms import ALGORITHMS
from dgtd.algorithms.actor import SoftmaxActor, action_advantage, own_values, policy, td_error, two_timescales
from dgtd.algorithms.stepsizes import step_sizes
from dgtd.algorithms.team_reward import (
    add_regression,
    add_slots,
    estimate,
    mean_step,
    mean_update,
    neighbourhood_slots,
    regression_rate,
    regression_step,
    slot_predictions,
)
from dgtd.channels import Arcs, Perfect
from dgtd.channels.base import BITS_PER_NUMBER
from dgtd.channels.inbox import HeldRows
from dgtd.errors import DgtdInputError
from dgtd.graphs.random import as_network
from dgtd.problems import team
from dgtd.run.checkpoint import assemble
from dgtd.run.layout import AllAgents, learner_layout
from dgtd.run.results import metrics_rows as run_rows
from dgtd.run.results import rows_csv
from dgtd.run.settings import check_count, kept_steps
from dgtd.run.state import AGENTS, ARCS, held, restore, snapshot
from dgtd.samples import Sample
from dgtd.sources.team_env import BLOCK, EnvTask, ModelEnv, SimulatorEnv
from dgtd.streams import ACTION, edge_uniforms, seed_keys, singles

ACTORS = ("networked", "independent", "centralised")
VALUES = ("state", "action")
TEAM_REWARDS = ("regression", "neighbourhood")  # networked agents' estimate of the team's reward (`team_reward`)
SCHEMES = ("zhang", "chen")  # Zhang et al.'s actor-critic (here), or Chen et al.'s Algorithm 1 (`dgtd.run.chen`)
OBJECTIVES = ("average", "discounted")  # what the actors ascend and J, J* measure (`dgtd.problems.team`)
LEARN_BACKENDS = ("numpy", "numba", "jax")  # the NumPy arithmetic below, or the agents' part compiled or on JAX
DISTRIBUTED = tuple(name for name, cls in ALGORITHMS.items() if not cls.centralised)  # the critics agents can have
METRICS = ("return", "critic_error", "entropy", "best_probability", "messages", "bits")


@dataclass(frozen=True)
class LearnSettings:
    """How long and how many: ``iterations`` steps of ``seeds`` seeds of base seed ``seed``, ``checkpoints`` of them
    measured; ``actor`` one of `ACTORS`; ``backend`` one of `LEARN_BACKENDS` (the agents' arithmetic in NumPy,
    compiled, `dgtd.backends.compiled.learner`, or on JAX, `dgtd.backends.jax_learner`: the same numbers to
    rounding); ``batch`` the steps of a round (Zhang et al.'s Algorithm 2 in mini-batches, the baseline of Chen, Zhou,
    Chen and Zou 2022, whose own Algorithm 1 is `dgtd.run.chen`: the agents communicate and move once a round, by the
    mean of its samples; 1 by default);
    ``values`` what the critics evaluate: "state" values V with a consensus estimate of the team's
    reward (Zhang et al.'s Algorithm 2, the default) or "action" values Q on the additive features f(s, a) (their
    Algorithm 1); ``objective`` what the actors ascend and J, J* measure: "average", the long-run average team reward
    (differential critics, `objective_terms`), or "discounted", the normalised discounted return from the start
    (critics discounted by the task's gamma); ``team_reward`` networked agents' estimate of the team's reward in their
    advantage: "regression", Zhang et al.'s (N A m numbers an agent, mixed over the links: O(N^2) a step in all), or
    "neighbourhood", each agent's regression of its neighbours' rewards on its own action (one number over each link
    a step, O(degree) an agent: `dgtd.algorithms.team_reward`)."""

    iterations: int = 20_000
    seeds: int = 2
    seed: int = 0
    checkpoints: int = 40
    actor: str = "networked"
    batch: int = 1
    values: str = "state"
    backend: str = "numba"
    objective: str = "average"
    team_reward: str = "regression"

    def __post_init__(self):
        if self.backend not in LEARN_BACKENDS:
            raise DgtdInputError(f"learners run on the {', '.join(LEARN_BACKENDS)} backend, not {self.backend!r}")
        if self.actor not in ACTORS:
            raise DgtdInputError(f"unknown actor {self.actor!r}; choose one of {', '.join(ACTORS)}")
        if self.objective not in OBJECTIVES:
            raise DgtdInputError(f"the objective is {' or '.join(OBJECTIVES)}, not {self.objective!r}")
        if self.team_reward not in TEAM_REWARDS:
            raise DgtdInputError(
                f"the team's reward is estimated by {' or '.join(TEAM_REWARDS)}, not {self.team_reward!r}"
            )
        if self.values not in VALUES:
            raise DgtdInputError(f"the critics evaluate {' or '.join(VALUES)} values, not {self.values!r}")
        for name in ("iterations", "seeds", "checkpoints", "batch"):
            if int(getattr(self, name)) < 1:
                raise DgtdInputError(f"{name} must be >= 1, got {getattr(self, name)}")
        object.__setattr__(self, "seed", check_count("seed", self.seed, 0))  # (-1 raised ValueError in the streams)
        if self.batch > self.iterations:  # (no round would end: nothing learned, and it said nothing)
            raise DgtdInputError(
                f"--batch {self.batch} steps a round need at least that many steps; -T {self.iterations} ends before "
                "the first round does: lower --batch or raise -T"
            )


@dataclass
class LearnResult:
    """``steps`` (C,) of the checkpoints; ``metrics`` {name: (C, B)}, checkpoints by seeds as a run's (`METRICS`:
    the exact return, the critics' error, the mean entropy, the least probability on the team's best action, the
    messages and bits delivered so far); ``policies`` (B, N, S, A_max) at the end; ``critic`` the critics' estimates
    (B, N or 1, q) at the end (both None on the ranks that do not write); ``return_best`` J* and ``best_action``
    (S,) the team's best joint action where computed; ``messages`` and ``bits`` (B,) delivered."""

    steps: np.ndarray
    metrics: dict
    policies: Any  # (B, N, S, A_max), or None
    critic: Any  # (B, N or 1, q), or None
    return_best: float | None
    best_action: np.ndarray | None
    messages: np.ndarray
    bits: np.ndarray
    seconds: float
    info: dict = field(default_factory=dict)


@dataclass
class Learners:
    """What a learning run carries from step to step, each field declared with what it holds (`dgtd.run.state.held`:
    a checkpoint saves, restores and puts together the ranks' shards from that alone, as a run's `RunState`): the
    step ``k``, what the actors see ``s`` (each seed's state (B,) on a model, the agents' features (B, N, d) in a
    simulator), each agent's actor ``theta`` and team-reward estimate ``lam`` (networked), the critics' state, the
    links' state and the metrics measured so far; under the average objective ``means`` (B, n, 2), each agent's
    running averages of its critic's reward and of the team's reward as it knows it."""

    k: int = held(default=0)
    s: Any = held()
    theta: Any = held(AGENTS, 1)
    lam: Any = held(AGENTS, 1)
    critic: Any = held(AGENTS, 1)  # the critic's NamedTuple state
    links: Any = held(ARCS, 1)  # the channel's state over the arcs into the agents held here
    metrics: Any = held(per_checkpoint=True)  # {name: (C, B)}
    pending: Any = held(saved=False)  # a round's sums so far: empty at every checkpoint (a round's end)
    means: Any = held(AGENTS, 1)
    tally: Any = held(saved=False)  # a simulator's sums since the last checkpoint (`TALLY`; no checkpoints there)
    diverged_at: Any = held()  # (B,) the checkpoint step at which a seed was found diverged, -1 while it has not
    steps: Any = held(default=None)  # (C,) the checkpoints' steps (a run extended to more steps keeps those it had)


@dataclass(frozen=True)
class LearnPlan:
    """What does not change over a learning run: the pieces, the keys, the step sizes and the checkpoints; ``env``
    what the agents act in (`dgtd.sources.team_env`), ``actor`` the actor it takes (tabular or linear)."""

    mdp: Any  # the problem: a team MDP, or a simulator's `EnvTask`
    network: Any
    critic: Any
    actor: SoftmaxActor
    settings: LearnSettings
    channel: Any
    arcs: Arcs
    keys: np.ndarray
    alphas: np.ndarray
    betas: np.ndarray
    at: np.ndarray
    rows: Any  # where the agents are held: `dgtd.run.layout.learner_layout`
    env: Any
    kernels: Any = None  # the agents' arithmetic compiled (`LearnerKernels`) or on JAX (`JaxLearners`), or None
    slots: Any = None  # the neighbourhood estimate's (members, arcs, valid) of the agents held here, or None
    block: int = BLOCK  # the steps of a block of the learners' draws (`_block_of`)


def learn(
    mdp,
    network,
    critic,
    actor: SoftmaxActor,
    settings: LearnSettings,
    channel=None,
    progress=None,
    *,
    checkpoint_every: int = 0,
    on_checkpoint=None,
    resume: dict | None = None,
    on_measured=None,
    checkpoint_seconds: float = 0.0,
):
    """Run the actor-critic of the module's docstring in ``mdp``, a team MDP or a simulator (`EnvTask`); ``critic``
    any distributed algorithm of `dgtd.algorithms` (its step sizes its own), ``channel`` the links (default perfect),
    ``progress(n)`` called as steps finish. Every ``checkpoint_every`` steps (or, where that is 0, at the first
    round's end once ``checkpoint_seconds`` > 0 have passed since the last save: `Saves`) ``on_checkpoint(snapshot)``
    is given the run's state (`dgtd.run.state.snapshot`); ``resume`` (one) continues from it to the numbers of the
    uninterrupted run, bit for bit (every random number is keyed by its step). ``on_measured(steps, metrics)`` is
    called as each checkpoint is measured, with the steps so far (c,) and each metric there (c, seeds), so that what
    was measured can be kept before the run ends."""
    network = as_network(network)  # (a bare graph: its fixed network; it raised AttributeError)
    plan = _plan(mdp, network, critic, actor, settings, channel)
    if checkpoint_every % settings.batch or (checkpoint_every and plan.env.estimated):
        raise DgtdInputError(
            "a simulator's state cannot be saved: no checkpoints to resume from"
            if plan.env.estimated
            else f"checkpoints fall at a round's end: --checkpoint-every {checkpoint_every} is not a multiple of the "
            f"--batch {settings.batch}"
        )
    started = time.perf_counter()
    best = (None, None) if plan.env.estimated else team.best_of(mdp, settings.objective)  # (J*, its joint actions)
    plan = replace(plan, at=kept_steps(plan.at, settings.iterations, resume))  # (a finished run extended: its own)
    run = _start(plan)
    if resume is not None:  # (its agents' rows taken by id, from whichever rank's shard holds them)
        whole_arcs = 2 * network.n_edges
        rows = assemble(resume, plan.env.n_agents, whole_arcs, plan.rows.local, plan.rows.arc_ids, state=Learners)
        run = restore(run, rows)
        run.steps = plan.at
    draws: tuple = ()
    saves = Saves(checkpoint_every, 0.0 if plan.env.estimated else checkpoint_seconds, settings.batch)
    for k in range(run.k, settings.iterations):
        if not draws or k % plan.block == 0:  # a block's numbers at once: each a pure function of (seed, purpose, step)
            first = k - k % plan.block
            draws = _draws(plan.keys, network, range(first, min(first + plan.block, settings.iterations)), plan.rows)
        _step(plan, run, draws, k)
        if k + 1 in plan.at:
            c = int(np.searchsorted(plan.at, k + 1))
            _record(plan, run, c, best[1])
            if on_measured is not None:
                on_measured(plan.at[: c + 1], {name: v[: c + 1] for name, v in run.metrics.items()})
            if (run.diverged_at >= 0).all():  # every seed has diverged: nothing is left to learn
                break
        if on_checkpoint and (saves.due(run.k) if run.k < settings.iterations else checkpoint_every):
            on_checkpoint(snapshot(run, plan.rows))
        if progress is not None:
            progress(1)
    return _result(plan, run, best, time.perf_counter() - started)


class Saves:
    """When a learning run saves its state: every ``every`` steps; or, ``every`` 0 and ``seconds`` > 0, at the
    first round's end (a multiple of ``batch`` steps) once that many seconds have passed since the last save or the
    start (a run resumes from any round's end to the same numbers). ``clock`` the time."""

    def __init__(self, every: int, seconds: float, batch: int, clock=time.perf_counter):
        self.every, self.seconds, self.batch, self.clock = int(every), float(seconds), int(batch), clock
        self.last = clock()

    def due(self, k: int) -> bool:
        """Whether to save after step k (k steps taken)."""
        if self.every:
            return k % self.every == 0
        if not self.seconds or k % self.batch:
            return False
        now = self.clock()
        if now - self.last < self.seconds:
            return False
        self.last = now
        return True


def distributed_critic(critic) -> None:
    """Refuse a centralised learner as the agents' critics."""
    if getattr(critic, "centralised", False):
        raise DgtdInputError(
            f"{critic.name} is one centralised learner; the agents' critics are a distributed method's: "
            f"{', '.join(DISTRIBUTED)}"
        )


def _plan(mdp, network, critic, actor, settings, channel) -> LearnPlan:
    distributed_critic(critic)
    two_timescales(actor, critic)
    keys = seed_keys(settings.seed, range(settings.seeds))
    env = _env(mdp, network, settings, keys)
    if network.n_nodes != env.n_agents:
        raise DgtdInputError(f"the network has {network.n_nodes} agents, the team MDP {env.n_agents}")
    T, N = settings.iterations, env.n_agents
    channel = channel if channel is not None else Perfect()
    whole = Arcs.of(network.base.edges, N)
    rows = AllAgents(N, whole) if env.estimated else learner_layout(N, whole, _weighs_by_counts(critic, settings))
    arcs = rows.arcs  # (the arcs into the agents held here, over the rows of what they hear)
    kernels = None if env.estimated else _kernels(settings.backend, critic, channel, arcs, rows)
    return LearnPlan(
        mdp, network, critic, env.actor(actor), settings, channel, arcs, keys,
        step_sizes(critic.schedule, critic.alpha0, critic.beta, 0, T), actor.steps(0, T),
        np.unique(np.linspace(0, T, settings.checkpoints + 1).round().astype(int)[1:]), rows, env, kernels,
        _slots(settings, channel, arcs, rows.own_rows), _block_of(settings.seeds, rows, network),
    )  # fmt: skip


def _slots(settings: LearnSettings, channel, arcs: Arcs, local: np.ndarray):
    """The neighbourhood estimate's slots of the agents held here (`neighbourhood_slots`), where asked; its rewards
    must arrive in the round they were earned (no late, compressed or asleep links)."""
    if settings.team_reward != "neighbourhood" or settings.actor != "networked" or settings.values != "state":
        return None
    neighbourhood_links(channel)
    return neighbourhood_slots(arcs.dst, arcs.src, local)


def neighbourhood_links(channel) -> None:
    """Refuse links the neighbourhood estimate cannot take: it pairs each reward heard with the step it was earned
    at, so messages may be lost, not late, compressed or sent by agents asleep."""
    late = getattr(channel, "delay", 0) or getattr(channel, "wake", None) is not None
    bits = getattr(channel, "bits", BITS_PER_NUMBER)
    compressed = getattr(channel, "top_k", None) is not None or bits < BITS_PER_NUMBER
    if late or compressed:
        raise DgtdInputError(
            "--team-reward neighbourhood pairs each neighbour's reward with the step it was earned at: its links may "
            "lose messages, not delay, compress or put agents to sleep (--delay, --bits, --top-k, --wake)"
        )


def _weighs_by_counts(critic, settings: LearnSettings) -> bool:
    """Whether the agents weigh what they hear by their neighbours' counts (Metropolis weights): the critic's mixing,
    or Zhang et al.'s team-reward regression, mixed so."""
    regression = settings.actor == "networked" and settings.values == "state" and settings.team_reward == "regression"
    return critic.mixing == "metropolis" or regression


def _env(mdp, network, settings: LearnSettings, keys):
    """What the agents act in: a model's steps, or a simulator's (`dgtd.sources.team_env`)."""
    if not isinstance(mdp, EnvTask):
        return ModelEnv(mdp, keys)
    if settings.values != "state" or settings.batch != 1:
        raise DgtdInputError(
            "in a simulator the critics evaluate state values, a step at a time (no --values, --batch)"
        )
    return SimulatorEnv(mdp, network, settings.seed, settings.seeds)


def _kernels(backend: str, critic, channel, arcs, rows):
    """The agents' arithmetic compiled (numba) or on JAX where asked (`LearnSettings.backend`; the same numbers to
    1e-12); None: NumPy's, as for a run the compiled kernels cannot take (`fallback`). JAX refuses, in one line, what
    it cannot run (JAX missing, links that hold copies), as `dgtd run --backend jax` does."""
    if backend == "jax":
        from dgtd.backends import jax as on_jax
        from dgtd.backends.jax_learner import JaxLearners

        on_jax.check_supported(channel)
        return JaxLearners(critic, arcs, rows.local, rows.own_rows)
    if backend == "numpy" or fallback(critic, channel) is not None:
        return None
    from dgtd.backends.compiled.learner import LearnerKernels

    return LearnerKernels(critic, arcs, rows.local, rows.own_rows)


def fallback(critic, channel) -> str | None:
    """Why learners with ``critic`` over ``channel`` run on the NumPy backend though the compiled one was asked (one
    line), or None."""
    from dgtd.backends.compiled.learner import learner_fallback

    return learner_fallback(critic, channel if channel is not None else Perfect())


def objective_terms(plan: LearnPlan, run: Learners, own: np.ndarray, rhat: np.ndarray, k: int) -> tuple:
    """(the critics' reward, their discount, the advantage's baseline) of step k's sample under the objective.
    Discounted: (own, gamma, 0). Average (Zhang et al. 2018, Algorithm 2: differential critics): (own - mu_i, 1,
    mu~_i), with mu_i the agent's running average of ``own`` and mu~_i of ``rhat``, the team's reward as it knows it
    (both (B, n)); their steps added to the round's, moved at its end (`round_end`)."""
    if run.means is None:
        return own, plan.mdp.gamma, 0.0
    pending = run.pending.setdefault("means", np.zeros_like(run.means))
    pending += mean_update(mean_step(k), np.stack(np.broadcast_arrays(own, rhat), axis=-1), run.means)
    return own - run.means[..., 0], 1.0, run.means[..., 1]


def _start(plan: LearnPlan) -> Learners:
    """A fresh run: uniform policies (or a problem file's), zero critics and estimates, what the actors first see;
    each agent's rows those held here (``plan.rows``)."""
    env, B, local, settings = plan.env, plan.settings.seeds, plan.rows.local, plan.settings
    theta = env.theta(plan.actor, B)
    n, A = len(local), int(env.actions.max())
    q = env.regression_size(A) if settings.values == "action" else env.n_features
    estimated = ("episode_return",) if env.estimated else ()
    lam = None
    if plan.slots is not None:  # (B, n, K, A, m): a regression on g(s) e_{a_i} of each slot's reward
        lam = np.zeros((B, n, plan.slots[0].shape[1], A, env.regression_size(1) // env.n_agents))
    elif settings.actor == "networked" and settings.values == "state":
        lam = np.zeros((B, n, env.regression_size(A)))
    return Learners(
        0, env.start(), np.ascontiguousarray(theta[:, local]), lam,
        plan.critic.init(B, n, q), plan.rows.init_channel(plan.channel, B, settings.seed),
        {name: np.full((len(plan.at), B), np.nan) for name in (*METRICS, *estimated)},
        {}, np.zeros((B, n, 2)) if settings.objective == "average" else None,
        np.zeros((B, len(TALLY))) if env.estimated else None, np.full(B, -1, dtype=np.int64), plan.at,
    )  # fmt: skip


def _step(plan: LearnPlan, run: Learners, draws: tuple, k: int) -> None:
    """Step k of the module's docstring, in place on ``run``: draw and act; the sample's critic directions, actor
    increments and reward-regression increments added to the round's (`Learners.pending`); at a round's last step
    (every ``batch`` steps, Zhang et al.'s Algorithm 2 in mini-batches; every step by default) hear and move
    (`round_end`)."""
    env, critic, kind, local = plan.env, plan.critic, plan.settings.actor, plan.rows.local
    B = run.theta.shape[0]
    pi = plan.actor.probabilities(run.theta, run.s)  # (B, n, A): the agents held here
    a_here = np.minimum(team.draw(np.cumsum(pi, axis=-1), draws[0][k % plan.block]), env.actions[local] - 1)
    a = plan.rows.gather(a_here)  # (B, N): every agent's action moves the state
    step = env.step(run.s, a, k)
    r = step.rewards[:, local]  # each agent's own reward
    own = np.broadcast_to(step.rewards.mean(axis=1, keepdims=True), r.shape) if kind == "centralised" else r
    if run.tally is not None:
        _tally(run.tally, step, pi)
    if plan.kernels is not None:
        _compiled_sample(plan, run, step, a, r, own, k)
        return _end_of(plan, run, draws, k, step.seen)
    W = critic.estimate(run.critic)  # (B, n, q)
    if plan.settings.values == "action":
        reward, gamma, _ = objective_terms(plan, run, own, own, k)
        phi, phi_next, delta = _action_values(plan, run, step.state, a, step.state_next, W)
        _add(plan, run, Sample(phi, phi_next, reward, np.ones((B, 1)), gamma), a_here, delta, k)
        return _end_of(plan, run, draws, k, step.seen)
    rhat = own if run.lam is None else team_estimate(plan, run, step, a, k)
    reward, discount, baseline = objective_terms(plan, run, own, rhat, k)
    gamma = discount if step.going is None else step.going[:, None] * discount  # (a terminal step: no bootstrap)
    phi, phi_next = step.phi, step.phi_next
    delta = td_error(rhat, baseline, gamma, (W * phi_next).sum(-1), (W * phi).sum(-1))
    _add(plan, run, Sample(phi, phi_next, reward, np.ones((B, 1)), gamma), a_here, delta, k)
    _end_of(plan, run, draws, k, step.seen)


def team_estimate(plan: LearnPlan, run: Learners, step, a: np.ndarray, k: int) -> np.ndarray:
    """rhat (B, n), the team's reward as each networked agent held here knows it at step k (``a`` every agent's
    action), its estimate's step on the sample added to the round's (`dgtd.algorithms.team_reward`): Zhang et al.'s
    regression of the agent's own reward over f(s, a), or the neighbourhood's, whose slots move at the round's end
    on the rewards heard (`heard_slots`)."""
    env, local = plan.env, plan.rows.local
    norm2 = 1.0 if step.g.ndim == 1 else np.maximum((step.g**2).sum(axis=1), 1e-12)[:, None]  # |g(s)|^2, (B, 1)
    r = step.rewards[:, local]
    if plan.slots is not None:
        predictions = slot_predictions(run.lam, a[:, local], step.g)  # (B, n, K)
        nu = np.broadcast_to(regression_rate(k, 1, norm2), (len(a), 1))[:, :, None]
        run.pending.setdefault("slots", []).append((a[:, local], step.g, predictions, nu, r))
        return predictions.sum(axis=-1) / env.n_agents
    A = int(env.actions.max())
    rhat = estimate(run.lam, a, step.g, A)
    lam = run.pending.setdefault("lam", np.zeros_like(run.lam))
    add_regression(lam, a, step.g, A, regression_step(regression_rate(k, env.n_agents, norm2), r, rhat))
    return rhat


def heard_slots(plan: LearnPlan, run: Learners, inbox) -> np.ndarray:
    """The sum over a round's steps of the neighbourhood estimate's moves (B, n, K, A, m): each slot's regression
    step on its member's reward of that step, where the round's message of it was heard (the agent's own always)."""
    members, arcs, valid = plan.slots
    heard = np.where(arcs >= 0, inbox.heard[:, np.maximum(arcs, 0)], 1.0) * valid  # (B, n, K)
    rewards = inbox.sent["reward"][:, members]  # (B, n, K, M): each member's rewards of the round's steps
    into = np.zeros_like(run.lam)
    for t, (a, g, predictions, nu, _) in enumerate(run.pending.pop("slots")):
        add_slots(into, a, g, heard * regression_step(nu, rewards[..., t], predictions))
    return into


def _compiled_sample(plan: LearnPlan, run: Learners, step, a, r, own, k: int) -> None:
    """`_step`'s arithmetic per agent, compiled (`dgtd.backends.compiled.learner`): the features of the seeds'
    transitions (rows phi(s), phi(s') of each seed in turn) handed to the kernel with the step's numbers."""
    mdp, (B, _, S, A) = plan.mdp, run.theta.shape
    if plan.settings.values == "action":
        phi, phi_next = _action_rows(plan, run, step.state, a, step.state_next)
    else:
        phi, phi_next = step.phi, step.phi_next
    rows = np.stack([phi[:, 0], phi_next[:, 0]], axis=1)
    regression = run.lam is not None and plan.slots is None  # (Zhang et al.'s: the kernel estimates)
    given = team_estimate(plan, run, step, a, k) if plan.slots is not None else own
    reward, gamma, baseline = objective_terms(plan, run, own, given, k)
    rhat, r_actor = np.zeros_like(own), given  # rhat: the kernel's estimates of the team's reward (regression)
    if run.lam is None:  # (the advantage's reward then the critic's, baseline and all)
        r_actor, baseline = reward, 0.0
    scal = (
        float(plan.betas[k]), float(regression_rate(k, mdp.n_agents)), float(gamma), S, A,
        plan.settings.values == "state", float(plan.actor.entropy),
    )  # fmt: skip
    plan.kernels.sample(
        run.critic, run.pending, run.theta, run.lam if regression else None, rows.reshape(2 * B, -1), step.state, a,
        r, reward, r_actor, scal, np.broadcast_to(baseline, own.shape), rhat,
    )  # fmt: skip
    if run.means is not None and regression:  # mu~_i's step on the estimates the kernel made, not own
        run.pending["means"][..., 1] += mean_update(mean_step(k), rhat, own)
    run.pending["n"] = run.pending.get("n", 0) + 1


def _add(plan: LearnPlan, run: Learners, sample: Sample, a, advantage, k: int) -> None:
    """A sample's critic directions and its actor step beta_k advantage psi added to the round's."""
    pending = run.pending
    d = plan.critic.directions(run.critic, sample)
    pending["d"] = tuple(x + y for x, y in zip(pending["d"], d)) if "d" in pending else d
    pending["theta"] = plan.actor.increment(run.theta, run.s, a, advantage, plan.betas[k], pending.get("theta"))
    pending["n"] = pending.get("n", 0) + 1


def _end_of(plan: LearnPlan, run: Learners, draws: tuple, k: int, seen) -> None:
    """Step k done: what the actors see next; at a round's end, `round_end` with the links up at step k."""
    run.s, run.k = seen, k + 1
    if run.k % plan.settings.batch == 0 or run.k == plan.settings.iterations:
        up = None if draws[1] is None else draws[1][k % plan.block]
        if plan.settings.actor == "independent":
            up = np.zeros((run.theta.shape[0], len(plan.rows.edges)), bool)  # they send nothing
        round_end(plan, run, up, k)


def _action_rows(plan: LearnPlan, run: Learners, s, a, s_next) -> tuple:
    """(f(s, a), E_pi f(s', .)) of the action-value critic (Zhang et al.'s Algorithm 1): the features dense
    (B, 1, N S A), the next ones expected under the current policies (expected SARSA). ``a`` every agent's actions."""
    B, n, S, A = run.theta.shape
    N = a.shape[1]
    b, mine = np.arange(B)[:, None], np.arange(n)[None, :]
    F = N * S * A
    phi, phi_next = np.zeros((B, 1, F)), np.zeros((B, 1, F))
    phi[b, 0, team.action_features(N, S, A, s, a)] = 1.0
    block = np.arange(N)[None, :, None] * S * A + np.arange(A)[None, None, :]  # (1, N, A): agent j's block, state 0
    after = plan.rows.gather(policy(run.theta[b, mine, s_next[:, None]]))  # (B, N, A): every agent's next policy
    phi_next[b[:, :, None], 0, block + (s_next * A)[:, None, None]] = after
    return phi, phi_next


def _action_values(plan: LearnPlan, run: Learners, s, a, s_next, W) -> tuple:
    """(f(s, a), E_pi f(s', .), agent i's advantage) of the action-value critic (`_action_rows`), the advantage
    A_i = Q_i(s, a) - sum_b pi_i(b | s) Q_i(s, b, a_-i), which on additive features is agent i's own block:
    w_i[i, s, a_i] - sum_b pi_i(b | s) w_i[i, s, b]. ``W`` and the advantage the agents held here (`plan.rows`)."""
    B, n, S, A = run.theta.shape
    b, mine = np.arange(B)[:, None], np.arange(n)[None, :]
    phi, phi_next = _action_rows(plan, run, s, a, s_next)
    own = own_values(np.broadcast_to(W, (B, n, phi.shape[-1])), plan.rows.local, s, S, A)  # w_i[i, s, .]
    advantage = action_advantage(own, policy(run.theta[b, mine, s[:, None]]), a[:, plan.rows.local])
    return phi, phi_next, advantage


def round_end(plan: LearnPlan, run: Learners, up, k: int) -> None:
    """A round's end: what every agent sends delivered once (independent agents send nothing), then the critics, the
    reward estimates and the actors moved by their round's mean (one sample's own, a round of one step)."""
    critic, pending, rows = plan.critic, run.pending, plan.rows
    n = pending.pop("n")
    sent = dict(critic.sends(run.critic))
    if plan.slots is not None:  # each agent's rewards of the round's steps: one number a step
        sent["reward"] = np.stack([x[-1] for x in pending["slots"]], axis=-1)
    elif run.lam is not None:
        sent["team"] = run.lam
    inbox, run.links = rows.hear(plan.channel, run.links, sent, up)
    if run.means is not None:
        run.means = run.means + pending.pop("means") / n
    if plan.slots is not None:
        run.lam = run.lam + heard_slots(plan, run, inbox) / n
    if plan.kernels is not None:
        run.critic = plan.kernels.move(run.critic, inbox, pending.pop("D") / n, plan.alphas[k])
        if run.lam is not None and plan.slots is None:
            run.lam = run.lam - plan.kernels.mixed(inbox, inbox.sent["team"], True) + pending.pop("lam") / n
        run.theta = run.theta + pending.pop("theta") / n
        return
    here = HeldRows(inbox, rows.own_rows)
    new = critic.moved(run.critic, tuple(x / n for x in pending.pop("d")), here, plan.alphas[k])
    if here.awake is not None:  # an asleep agent keeps its state, as in `dgtd run`
        new = new._make(np.where(here.awake[:, :, None], x, old) for x, old in zip(new, run.critic))
    run.critic = new
    if run.lam is not None and plan.slots is None:
        run.lam = run.lam - metropolis(inbox, plan.arcs, "team")[:, rows.own_rows] + pending.pop("lam") / n
    run.theta = run.theta + pending.pop("theta") / n


def _draws(keys: np.ndarray, network, steps: range, rows) -> tuple:
    """The uniforms of ``steps``: the action of each agent held here (``rows``: `learner_layout`) (T, B, n), and the
    links up of the edges drawn here (T, B, E') or None where every link is always up (a model's next states are its
    own: `ModelEnv`)."""
    k = np.arange(steps.start, steps.stop, dtype=np.uint64)[:, None, None]
    action = singles(keys[None, :, None], ACTION, k, rows.local)
    if network.fixed:
        return action, None
    p = np.asarray(network.p)
    return action, edge_uniforms(keys, k, network.base.edges[rows.edges]) < (p if p.ndim == 0 else p[rows.edges])


DRAWS_BUDGET = 1 << 18  # numbers (2 MB; their draws' working arrays some times that) a block of the learners' draws may
# hold: fewer steps where agents are many


def _block_of(seeds: int, rows, network) -> int:
    """The steps of a block of the learners' draws (`_draws`): `BLOCK`, fewer where a block of the numbers of the
    agents held here and of the edges drawn here (``rows``: `learner_layout`) would pass `DRAWS_BUDGET` (every
    number is keyed by its step: any block draws the same)."""
    width = len(rows.local) + (0 if network.fixed else len(rows.edges))
    return int(min(BLOCK, max(1, DRAWS_BUDGET // (seeds * width))))


TALLY = ("reward", "entropy", "steps", "returns", "episodes", "episode")  # a simulator's sums between checkpoints


def _tally(tally: np.ndarray, step, pi: np.ndarray) -> None:
    """A simulator's step added to its seeds' sums since the last checkpoint (`TALLY`): the team's mean reward, the
    policies' mean entropy, a step; the returns of the episodes that ended and their number; and the team's return
    of the episode under way."""
    rbar = step.rewards.mean(axis=1)
    entropy = -(pi * np.log(np.where(pi > 0, pi, 1.0))).sum(axis=-1).mean(axis=1)
    episode = tally[:, 5] + rbar
    tally[:, :5] += np.stack([rbar, entropy, np.ones_like(rbar), np.where(step.ended, episode, 0.0), step.ended], 1)
    tally[:, 5] = np.where(step.ended, 0.0, episode)


def _record(plan: LearnPlan, run: Learners, c: int, best_action) -> None:
    """Checkpoint c's metrics: exact on a model (`_measure`), estimated from the run's own rewards in a simulator
    (the team's mean reward a step and the mean return of the episodes ended since the last checkpoint, NaN where
    none did), and the messages and bits delivered so far. A seed whose critics or actors have left the finite
    numbers is marked diverged (`Learners.diverged_at`): its metrics NaN from then on."""
    theta, W = run.theta, plan.critic.estimate(run.critic)  # (the agents held here)
    B = theta.shape[0]  # (theta's -inf: an action an agent does not have)
    finite = np.isfinite(W.reshape(B, -1)).all(1) & ~(np.isnan(theta) | np.isposinf(theta)).reshape(B, -1).any(1)
    run.diverged_at[~plan.rows.every(finite) & (run.diverged_at < 0)] = plan.at[c]
    if run.tally is None:  # (on the process that writes: the others' metrics are not read)
        theta, W = plan.rows.gather_root(theta), plan.rows.gather_root(W)
        if theta is not None:
            measure(plan.mdp, theta, W, run.metrics, c, plan.settings, best_action)
    else:
        tally = run.tally
        run.metrics["return"][c], run.metrics["entropy"][c] = tally[:, 0] / tally[:, 2], tally[:, 1] / tally[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            run.metrics["episode_return"][c] = np.where(tally[:, 4] > 0, tally[:, 3] / tally[:, 4], np.nan)
        tally[:, :5] = 0.0
        for name in ("return", "entropy", "episode_return"):
            run.metrics[name][c, run.diverged_at >= 0] = np.nan
    run.metrics["messages"][c], run.metrics["bits"][c] = run.links.messages, run.links.bits


def _result(plan: LearnPlan, run: Learners, best: tuple, seconds: float) -> LearnResult:
    """A finished run's `LearnResult`: the policies (a simulator's: its actors' weights), the critics, J*; over
    ranks, every agent's on the rank that writes (None on the others)."""
    theta = plan.rows.gather_root(run.theta)
    info: dict = {"objective": plan.settings.objective, "diverged_at": run.diverged_at.tolist()}
    if run.k < plan.settings.iterations:  # (every seed diverged)
        info["stopped_at"] = run.k
    if plan.env.estimated:
        info |= {"backend": "numpy", "agents": plan.env.agents, "estimated": True}
    else:
        info |= {"backend": "numpy" if plan.kernels is None else plan.settings.backend}
    return LearnResult(
        plan.at, run.metrics, theta if plan.env.estimated or theta is None else policy(theta),
        plan.rows.gather_root(plan.critic.estimate(run.critic)), best[0], best[1], run.links.messages, run.links.bits,
        seconds, info,
    )  # fmt: skip


def metropolis(inbox, arcs: Arcs, name: str) -> np.ndarray:
    """`Inbox.metropolis` of a long message (the team-reward estimate: N S A numbers) as one (N, N) mixing matrix
    per seed, built from the arcs heard, times the messages, on dense graphs (N^2 <= 4 x arcs), where the arcs' gather
    of (B, 2E, q) numbers costs more. Where the channel changed what arrived (late or compressed copies), or the graph
    is sparse, the inbox's own."""
    B, N = inbox.heard.shape[0], arcs.n_agents
    if name in inbox.received or not arcs.dense:  # (sparse graphs: the arcs' own sums are the cheaper)
        return inbox.metropolis(name)
    d = inbox.count()
    weights = inbox.heard / (1.0 + np.maximum(d[:, arcs.dst], d[:, arcs.src]))  # W_ij of each arc j -> i heard
    W = np.zeros((B, N, N))
    np.add.at(W, (np.arange(B)[:, None], arcs.dst[None, :], arcs.src[None, :]), weights)
    x = inbox.sent[name]
    return W.sum(axis=2)[:, :, None] * x - W @ x


def local_policies(mdp: team.TeamMDP, pi: np.ndarray) -> list:
    """One seed's policies (N, S, A_max) as the agents' own arrays, (S, A_i) each."""
    return [pi[i, :, :n] for i, n in enumerate(mdp.actions)]


def measure(mdp: team.TeamMDP, theta: np.ndarray, W: np.ndarray, metrics: dict, c: int, settings, best_action) -> None:
    """The exact return of each seed's current policies under the run's objective, its critics' error against their
    exact critic, the mean entropy, and the least probability any agent puts on its part of the team's best action
    (where known)."""
    pi = policy(theta)
    for b in range(theta.shape[0]):
        if not (np.isfinite(pi[b]).all() and np.isfinite(W[b]).all()):  # a diverged seed: NaN, its numbers gone
            for name in ("return", "critic_error", "entropy", "best_probability"):
                metrics[name][c, b] = np.nan
            continue
        policies = local_policies(mdp, pi[b])
        P_pi, _ = team.chain_of(mdp, policies)
        metrics["return"][c, b] = team.objective_return(mdp, policies, settings.objective)
        W_b = np.broadcast_to(W[b], (mdp.n_agents, W.shape[-1]))
        own = settings.actor == "independent"
        metrics["critic_error"][c, b] = _critic_error(mdp, policies, W_b, settings.values, settings.objective, own)
        metrics["entropy"][c, b] = team.entropy(policies, team.long_run(P_pi, mdp.start)).mean()
        if best_action is not None:  # (the objective's: under the discounted one it may differ)
            best = mdp.local(best_action)  # (S, N)
            metrics["best_probability"][c, b] = min(
                float(p[np.arange(mdp.n_states), best[:, i]].min()) for i, p in enumerate(policies)
            )


def _critic_error(mdp, policies, W: np.ndarray, values: str, objective: str = "discounted", own=False) -> float:
    """|W - W*(pi)|^2 / |W*|^2 over the agents' critics (Chen et al.'s, W* every agent's target: the team's, or with
    ``own`` each agent's own reward's, an independent learner's) for discounted state values; for action values,
    whose additive features are dependent (`dgtd.problems.team.action_critic_target`), and for differential values
    (the average objective: defined up to a constant), the same in values, each less its d-weighted mean under the
    average objective: sum_i |Phi (w_i - w_i*)|_d^2 / sum_i |Phi w_i*|_d^2, the denominator at least N times the
    spread of the rewards the critics are fed there (`_reward_spread`: a policy whose team reward is the same in
    every state has flat differential values, beside which any error would look huge); NaN where there is no joint
    table to solve on."""
    agents = range(mdp.n_agents) if own else [None]
    if values == "state":
        Phi, d = mdp.Phi, team.long_run(team.chain_of(mdp, policies)[0], mdp.start)
        targets = list(team.critic_targets(mdp, policies, objective, agents))
    else:
        solved = [team.action_critic_target(mdp, policies, objective, i) for i in agents]
        if solved[0] is None:
            return float("nan")
        (Phi, d, _), targets = solved[0], [t for _, _, t in solved]  # type: ignore[misc]
    target = np.broadcast_to(np.array(targets), W.shape)
    if values == "state" and objective == "discounted":
        return float(((W - target) ** 2).sum() / max(float((target**2).sum()), 1e-300))
    gaps, scale = Phi @ (W - target).T, Phi @ target.T
    size = float((scale**2 * d[:, None]).sum())
    if objective == "average":  # (differential values: the constant is free)
        gaps, scale = gaps - d @ gaps, scale - d @ scale
        size = max(float((scale**2 * d[:, None]).sum()), mdp.n_agents * _reward_spread(mdp, policies))
    return float((gaps**2 * d[:, None]).sum() / max(size, 1e-300))


def _reward_spread(mdp, policies) -> float:
    """The mean over the agents of E (r_i - J_i)^2, the spread of the rewards each agent's critic is fed, over the
    long-run states and the policies' actions: R_i(s, a) over joint actions (a joint table), R_i(s, a_i) over the
    agent's own (a factored MDP)."""
    P_pi, _ = team.chain_of(mdp, policies)
    d = team.long_run(P_pi, mdp.start)
    if isinstance(mdp, team.TeamMDP):
        weights = np.broadcast_to((d[:, None] * team.joint_policy(policies)).ravel(), (mdp.n_agents, mdp.R[0].size))
    else:
        weights = np.stack([(d[:, None] * p).ravel() for p in policies])
    R = mdp.R.reshape(mdp.n_agents, -1)
    J = (weights * R).sum(axis=1, keepdims=True)
    return float(np.mean((weights * (R - J) ** 2).sum(axis=1)))


POLICY_JSON = 200_000  # the most numbers of the last policies (seeds x agents x states x actions) summary.json holds


def summary(result: LearnResult, mdp, record: dict) -> dict:
    """summary.json of a learning run: what was asked, the exact best J* where computed, and per seed the last
    policies (`policy_last`: [seeds][agents] arrays (S, A_i) of action probabilities; None beyond `POLICY_JSON`
    numbers, a JSON text of hundreds of megabytes: they are in policies.npz, as always), their exact return
    (`return_last`, J of exactly those policies), the last critics' error and the counts of what was sent; in a
    simulator (``mdp`` an `EnvTask`), the estimated returns instead (`_estimated_summary`)."""
    if isinstance(mdp, EnvTask):
        return _estimated_summary(result, mdp, record)
    policies = None  # (beyond `POLICY_JSON`: in policies.npz alone)
    if result.policies.size <= POLICY_JSON:
        policies = [[p.tolist() for p in local_policies(mdp, pi)] for pi in result.policies]
    return {
        "task": mdp.name,
        "n_states": mdp.n_states,
        "n_agents": mdp.n_agents,
        "actions": list(mdp.actions),
        "gamma": mdp.gamma,
        "config": record,
        "return_best": result.return_best,
        "best_action": None if result.best_action is None else mdp.local(result.best_action).tolist(),
        "objective": result.info.get("objective", "average"),
        "return_last": [
            team.objective_return(mdp, local_policies(mdp, pi), result.info.get("objective", "average"))
            if np.isfinite(pi).all()
            else None  # (a diverged seed)
            for pi in result.policies
        ],
        "critic_error_last": result.metrics["critic_error"][-1].tolist(),
        "best_probability_last": result.metrics["best_probability"][-1].tolist(),
        "policy_last": policies,
        "diverged_at": diverged(result),
        "messages": result.messages.tolist(),
        "bits": result.bits.tolist(),
        "seconds": result.seconds,
    }


def diverged(result: LearnResult) -> list:
    """Each seed's step at which it was found diverged, or None (summary.json's ``diverged_at``)."""
    return [None if k < 0 else int(k) for k in result.info.get("diverged_at", [])]


def metrics_rows(results: dict):
    """(label, seed, step, metric, value) of learning runs {label: `LearnResult`}, as a run's
    (`dgtd.run.results.metrics_rows`: every metric, checkpoint and seed)."""
    for label, result in results.items():
        yield from run_rows(result, label)


def metrics_csv(results: dict, column: str) -> bytes:
    """metrics.csv of learning runs {label: `LearnResult`} (`dgtd.run.results.rows_csv`), the label's column named
    ``column`` ("actor" for one run, "learners" for a comparison)."""
    return rows_csv(metrics_rows(results), column)


def _estimated_summary(result: LearnResult, task: EnvTask, record: dict) -> dict:
    """summary.json of learners in a simulator: what was asked and, per seed, the team's mean reward a step over the
    last interval (``return_last``, estimated: ``return_estimated``); no J* and no policy tables (no model)."""
    return {
        "task": task.name,
        "n_agents": task.n_agents,
        "agents": result.info["agents"],
        "gamma": task.gamma,
        "objective": result.info["objective"],
        "config": record,
        "return_estimated": True,
        "return_first": result.metrics["return"][0].tolist(),
        "return_last": result.metrics["return"][-1].tolist(),
        "episode_return_first": _listed(result.metrics["episode_return"][0]),
        "episode_return_last": _listed(result.metrics["episode_return"][-1]),
        "return_best": None,
        "entropy_last": result.metrics["entropy"][-1].tolist(),
        "diverged_at": diverged(result),
        "messages": result.messages.tolist(),
        "bits": result.bits.tolist(),
        "seconds": result.seconds,
    }


def _listed(x: np.ndarray) -> list:
    """Numbers as JSON holds them: NaN (no episode ended in the interval) as null."""
    return [None if not np.isfinite(v) else float(v) for v in x]
