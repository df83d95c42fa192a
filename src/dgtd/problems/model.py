"""The canonical multi-agent policy-evaluation problem (paper section 'Distributed reinforcement learning overview').

Every problem, whether given as a Markov reward process or as a multi-agent MDP, is reduced to one
`Problem`: the target chain P^pi and the agents' expected rewards r_i^pi (what the exact solution needs),
and a behaviour sampling model (what the agents see). On-policy, the sampling model is P itself with one
dummy action and importance ratio 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from dgtd.errors import DgtdInputError

ROW_SUM_TOL = 1e-8
REWARD_NOISES = ("none", "bernoulli", "uniform", "transition")
RESTARTS = ("sampled", "skipped")  # what an episodic task's restart transition is: a sample, or not one


@dataclass(frozen=True, eq=False)
class Problem:
    """A multi-agent policy-evaluation problem in Markov reward process form.

    Shapes (S states, N agents, q features, A joint actions of the behaviour sampling model):

    - ``P`` (S, S): target-policy transition matrix P^pi.
    - ``R`` (N, S): expected reward of each agent under the target policy, r_i^pi(s).
    - ``Phi`` (S, q): features, full column rank; row s is phi(s).
    - ``gamma``: discount factor in (0, 1); 1 is allowed for an episodic task (``terminal``), whose every
      state reaches a terminal one.
    - ``P_sample`` (S, A, S): behaviour probability of (a, s') given s, beta(a|s) P(s, a, s').
    - ``ratio`` (S, A): importance ratio pi(a|s) / beta(a|s) (ones on-policy).
    - ``R_sample`` (N, S, A): mean reward of agent i given (s, a). The updates use the reward only through
      phi(s) and the ratio of (s, a), so this mean is all the sampler needs to be exact in expectation.
    - ``sigma``: rewards lie in [0, sigma] (paper section 3); it sizes the projection boxes.
    - ``reward_noise``: how a sample's reward is drawn: 'none' (the mean E[r | s, a], deterministic), 'bernoulli'
      (sigma * Bernoulli(mean / sigma)), 'uniform' (uniform on [m - h, m + h], h = min(m, sigma - m)), each with
      the stated mean and support, or 'transition': the reward of the sampled transition r(s, a, s') (the paper's
      r-hat), for a problem that gives rewards per transition (``R_transition``).
    - ``R_transition`` (N, S, A, S) or None: agent i's reward r_i(s, a, s') where the problem gives it (a
      multi-agent MDP with rewards per transition); R_sample is its expectation over s'.
    - ``w0`` (q,) or None: the task's prescribed initial value weights (Baird's counterexample starts at
      (1, 1, 1, 1, 1, 1, 10, 1)); None means zero, Algorithm 1 line 3.
    - ``terminal`` (S,) bool: terminal states of an episodic task. The discount of a transition s -> s' is
      gamma(s, s') = gamma c(s) c(s') with c = 0 at a terminal state, 1 elsewhere: a transition into a terminal
      state ends the return (the terminal's value is 0), and the terminal's own transition is the restart, whose
      row of P is the restart distribution and which carries nothing over into the next episode (Sutton and
      Barto 2018, section 3.4; White 2017, transition-based discounting). All False: a continuing task.
    - ``restarts``: 'sampled' (dgtd's convention): the terminal state's restart transition is a sample like any
      other, so d weights the terminal state too; 'skipped' (the RL-Glue suites', e.g. Regularized-GradientTD):
      an episode's samples are its transitions out of non-terminal states, the next sample after a transition
      into a terminal state starts at the restart's state, and d is the chain's stationary distribution
      conditioned on a non-terminal state (`with_restarts`).
    """

    P: np.ndarray
    R: np.ndarray
    Phi: np.ndarray
    gamma: float
    P_sample: np.ndarray
    ratio: np.ndarray
    R_sample: np.ndarray
    sigma: float
    reward_noise: str = "none"
    name: str = "problem"
    state_labels: tuple = field(default=())
    w0: np.ndarray | None = None
    terminal: np.ndarray | None = None
    R_transition: np.ndarray | None = None
    restarts: str = "sampled"

    @property
    def reward_table(self) -> np.ndarray:
        """(N, S, A, S') of the rewards a sample draws from: r_i(s, a, s') for reward noise 'transition', else the
        mean E[r_i | s, a] as a table with S' = 1 (a view: the same whichever the next state)."""
        if self.reward_noise == "transition":
            assert self.R_transition is not None, "reward noise 'transition' needs rewards per transition"
            return self.R_transition
        return self.R_sample[..., None]

    @property
    def skipped_terminals(self) -> np.ndarray | None:
        """The terminal flags a Markovian sampler reads where restarts are not samples (``restarts`` 'skipped'): a
        trajectory reaching one goes on from the restart's state; else None."""
        return self.terminal if self.restarts == "skipped" else None

    @property
    def continuing(self) -> np.ndarray:
        """c (S,): 0 at a terminal state, 1 elsewhere; gamma(s, s') = gamma c(s) c(s')."""
        return np.ones(self.P.shape[0]) if self.terminal is None else 1.0 - self.terminal

    @property
    def P_discounted(self) -> np.ndarray:
        """The discounted transition matrix gamma(s, s') P(s, s') of the Bellman equation J = r + P_discounted J."""
        c = self.continuing
        return self.gamma * (c[:, None] * self.P * c[None, :])

    @property
    def n_states(self) -> int:
        return self.P.shape[0]

    @property
    def n_agents(self) -> int:
        return self.R.shape[0]

    @property
    def n_features(self) -> int:
        return self.Phi.shape[1]

    @property
    def n_actions(self) -> int:
        return self.P_sample.shape[1]

    @property
    def off_policy(self) -> bool:
        return not np.all(self.ratio == 1.0)

    @property
    def P_behaviour(self) -> np.ndarray:
        """Behaviour state chain sum_a beta(a|s) P(s, a, s'), shape (S, S)."""
        return self.P_sample.sum(axis=1)


def _as_float_array(name: str, x, ndim: int) -> np.ndarray:
    try:
        a = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise DgtdInputError(f"{name} must be a numeric array ({e})") from None
    if a.ndim != ndim:
        raise DgtdInputError(f"{name} must have {ndim} dimensions, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise DgtdInputError(f"{name} contains NaN or infinite values; replace them with finite numbers")
    return a


def check_stochastic(name: str, P: np.ndarray) -> None:
    """Refuse NaN or infinite entries, negative ones and rows that do not sum to one: each row is a probability
    distribution (a transition matrix's, a policy's)."""
    if not np.isfinite(P).all():
        s = int(np.argwhere(~np.isfinite(P))[0][0])
        raise DgtdInputError(f"{name} holds NaN or infinite values (first in row {s}); probabilities must be finite")
    if np.any(P < 0):
        s = int(np.argwhere(P < 0)[0][0])
        raise DgtdInputError(f"{name} has negative entries (first in row {s}); probabilities must be >= 0")
    sums = P.reshape(P.shape[0], -1).sum(axis=1)
    bad = np.flatnonzero(np.abs(sums - 1.0) > ROW_SUM_TOL)
    if bad.size:
        s = int(bad[0])
        raise DgtdInputError(
            f"row {s} of {name} sums to {sums[s]:.10g}, not 1; each row is a probability distribution and must sum to 1"
        )


def chain_period(P: np.ndarray) -> int:
    """Period of an irreducible chain: gcd of level(u) + 1 - level(v) over the edges u -> v of a BFS tree."""
    S = P.shape[0]
    level = np.full(S, -1)
    level[0] = 0
    frontier: list = [0]
    while frontier:
        nxt: list = []
        for u in frontier:
            for v in np.flatnonzero(P[u] > 0):
                if level[v] < 0:
                    level[v] = level[u] + 1
                    nxt.append(v)
        frontier = nxt
    tails, heads = np.nonzero(P > 0)
    return int(np.gcd.reduce(np.abs(level[tails] + 1 - level[heads])))


def check_irreducible(name: str, P: np.ndarray) -> None:
    """Refuse a chain with more than one communicating class: its stationary distribution is not unique."""
    from dgtd.graphs.topologies import all_reachable

    A = P > 0
    if all_reachable(A) and all_reachable(A.T):
        return
    from scipy.sparse.csgraph import connected_components

    n, labels = connected_components(P > 0, directed=True, connection="strong")
    if n > 1:
        sizes = np.bincount(labels)
        raise DgtdInputError(
            f"{name} is not ergodic: its states form {n} separate communicating classes (sizes "
            f"{sizes.tolist()[:6]}); make every state reachable from every other"
        )


MEMORY_LIMIT_GB = 8.0
"""Default largest memory the dense exact solution may take; the environment variable DGTD_MEMORY_LIMIT_GB
raises (or lowers) it."""


def size_estimate(problem) -> tuple[float, float]:
    """(bytes, seconds) the dense exact solution of ``problem`` takes, roughly: the stationary distribution is a
    least-squares solve on an (S + 1) x S matrix (several copies of it in LAPACK's workspace, O(S^3) flops), and
    A = Phi^T D (I - gamma P) Phi needs P Phi (O(S^2 q)); the seconds assume 20 GFLOP/s."""
    S, q = problem if isinstance(problem, tuple) else (problem.n_states, problem.n_features)
    n_bytes = 8.0 * (5.0 * S * S + 4.0 * S * q + 4.0 * q * q)
    flops = 4.0 * S**3 + 2.0 * S * S * q + 2.0 * S * q * q + 10.0 * q**3
    return n_bytes, flops / 20e9


def check_size(problem) -> None:
    """Refuse, in one line, a problem (or its (states, features)) whose exact solution would take more memory
    than the limit, before anything of that size is computed."""
    import os

    raw = os.environ.get("DGTD_MEMORY_LIMIT_GB")
    try:
        limit = MEMORY_LIMIT_GB if raw is None else float(raw)
    except ValueError:
        raise DgtdInputError(f"DGTD_MEMORY_LIMIT_GB must be a number of gigabytes, got {raw!r}") from None
    S, q = problem if isinstance(problem, tuple) else (problem.n_states, problem.n_features)
    n_bytes, seconds = size_estimate((S, q))
    if n_bytes > limit * 1e9:
        raise DgtdInputError(
            f"the exact solution of this problem ({S:,} states, {q:,} features) "
            f"takes about {n_bytes / 1e9:.1f} GB and {seconds / 60:.0f} min of dense linear algebra, over the limit of "
            f"{limit:g} GB; use fewer states or features, or raise the limit with DGTD_MEMORY_LIMIT_GB"
        )


def check_reward_noise(reward_noise: str, R_transition) -> None:
    """A known way of drawing rewards, and rewards per transition where it draws those."""
    if reward_noise not in REWARD_NOISES:
        raise DgtdInputError(f"reward_noise must be one of {', '.join(REWARD_NOISES)}, got {reward_noise!r}")
    if reward_noise == "transition" and R_transition is None:
        raise DgtdInputError(
            "reward noise 'transition' draws the reward of each sampled transition r(s, a, s'), but "
            "this problem gives rewards per state (and action) only; give rewards of shape "
            "(N, S, A, S) in a multi-agent MDP, or choose another reward noise"
        )


def with_reward_noise(problem: Problem, reward_noise: str) -> Problem:
    """The same problem with another way of drawing rewards, checked as `make_problem` checks it."""
    check_reward_noise(reward_noise, problem.R_transition)
    return replace(problem, reward_noise=reward_noise)


def with_restarts(problem: Problem, restarts: str) -> Problem:
    """The same episodic task under the other convention of what a sample is (`Problem.restarts`)."""
    if restarts not in RESTARTS:
        raise DgtdInputError(f"restarts must be one of {', '.join(RESTARTS)}, got {restarts!r}")
    if restarts == "skipped":
        if problem.terminal is None:
            raise DgtdInputError(
                f"restarts = skipped applies to an episodic task (one with terminal states); {problem.name} is "
                "continuing"
            )
        restart = problem.P_behaviour[problem.terminal]
        if (restart[:, problem.terminal] > 0).any():
            raise DgtdInputError(
                "restarts = skipped needs every restart to start at a non-terminal state; this task's terminal "
                "states restart into terminal ones"
            )
    return replace(problem, restarts=restarts)


def make_problem(
    P,
    R,
    Phi,
    gamma: float,
    *,
    P_sample=None,
    ratio=None,
    R_sample=None,
    sigma: float | None = None,
    reward_noise: str = "none",
    name: str = "problem",
    state_labels: tuple = (),
    w0=None,
    signed_rewards: bool = False,
    dependent_features: bool = False,
    terminal=None,
    R_transition=None,
) -> Problem:
    """Validate and build a `Problem`; on-policy when no sampling model is given.

    Every check raises `DgtdInputError` with a message naming what is wrong. Two checks can be relaxed for
    benchmark tasks that need it, and only on request:

    - ``signed_rewards``: mean rewards may be negative, |r| <= sigma, as in Boyan's chain (-3 per step) and in
      Baird's counterexample (zero reward, which agents can only split into differing parts with signs).
      The paper's bounds use |r| <= sigma only; the reward-noise models draw on [0, sigma], so the run
      refuses noise for such a problem.
    - ``dependent_features``: Phi may lack full column rank, as in Baird's counterexample (8 features for
      7 states). The exact solution is then the one reached from ``w0``: every update moves w along feature
      vectors, so w - w0 stays in the row space of Phi (`dgtd.problems.exact.w_star`).
    """
    shape_P, shape_Phi = np.shape(P), np.shape(Phi)
    if len(shape_P) == 2 and len(shape_Phi) == 2:
        check_size((shape_P[0], shape_Phi[1]))  # first: even checking arrays this large takes long
    P = _as_float_array("P", P, 2)
    R = _as_float_array("R", R, 2)
    Phi = _as_float_array("Phi", Phi, 2)
    try:
        gamma = float(gamma)
    except (TypeError, ValueError):
        raise DgtdInputError(f"gamma must be a number, got {gamma!r}") from None
    terminal = _terminal_flags(terminal, P.shape[0])
    _check_model(P, R, Phi, gamma, terminal, dependent_features)
    P_sample, ratio, R_sample = _sampling_model(P, R, P_sample, ratio, R_sample)
    if R_transition is not None:
        R_transition = _transition_rewards(R_transition, P_sample, R_sample)
    check_reward_noise(reward_noise, R_transition)
    P_beh = P_sample.sum(axis=1)
    check_irreducible("the behaviour chain" if P_sample.shape[1] > 1 or not np.array_equal(P_beh, P) else "P", P_beh)
    sigma = _sigma(sigma, R, R_sample, R_transition, signed_rewards, reward_noise)
    if w0 is not None:
        w0 = _as_float_array("w0", w0, 1)
        if w0.shape != (Phi.shape[1],):
            raise DgtdInputError(f"w0 must have one entry per feature ({Phi.shape[1]}), got shape {w0.shape}")
    for x in (P, R, Phi, P_sample, ratio, R_sample, terminal, R_transition, w0):
        if x is not None:
            x.setflags(write=False)
    return Problem(
        P,
        R,
        Phi,
        gamma,
        P_sample,
        ratio,
        R_sample,
        sigma,
        reward_noise,
        name,
        tuple(state_labels),
        w0,
        terminal,
        R_transition,
    )


def _terminal_flags(terminal, S: int) -> np.ndarray | None:
    """An episodic task's terminal flags (S,) as booleans, or None where there are none."""
    if terminal is None:
        return None
    terminal = np.asarray(terminal)
    if terminal.dtype.kind in "fc" and not np.isfinite(terminal).all():
        at = int(np.flatnonzero(~np.isfinite(terminal))[0])
        raise DgtdInputError(f"terminal holds {terminal[at]} at state {at}: give 1 at a terminal state, 0 elsewhere")
    if terminal.shape != (S,) or terminal.dtype.kind not in "biu" or not np.isin(terminal, (0, 1)).all():
        raise DgtdInputError(
            f"terminal must be {S} flags (1 at a terminal state, 0 elsewhere), one per state, got "
            f"shape {terminal.shape}"
        )
    return terminal.astype(bool) if terminal.any() else None


def _check_model(P, R, Phi, gamma: float, terminal, dependent_features: bool) -> None:
    """gamma, the shapes of P, R and Phi, numbers in range, P stochastic, episodes that end where gamma = 1, Phi's
    rank."""
    S, episodic = P.shape[0], terminal is not None
    if S == 0:
        raise DgtdInputError(f"P has no states (shape {P.shape}): a problem needs at least one")
    if Phi.ndim == 2 and Phi.shape[1] == 0:
        raise DgtdInputError(f"Phi has no features (shape {Phi.shape}): give at least one column")
    _check_range(R, Phi)
    if not np.isfinite(gamma) or not (0.0 < gamma < 1.0 or (episodic and gamma == 1.0)):
        raise DgtdInputError(
            f"gamma must lie strictly between 0 and 1 (or be 1 in an episodic task, with terminal states), got {gamma}"
        )
    if P.shape != (S, S):
        raise DgtdInputError(f"P must be square (S, S), got shape {P.shape}")
    if R.shape[1] != S:
        raise DgtdInputError(f"R must have shape (N, S) = (N, {S}) to match P, got {R.shape}")
    if Phi.shape[0] != S:
        raise DgtdInputError(f"Phi must have shape (S, q) = ({S}, q) to match P, got {Phi.shape}")
    if R.shape[0] < 1:
        raise DgtdInputError("R must hold at least one agent (one row)")
    check_stochastic("P", P)
    if episodic and gamma == 1.0:
        c = 1.0 - terminal
        if np.max(np.abs(np.linalg.eigvals(c[:, None] * P * c[None, :]))) >= 1.0 - 1e-12:
            raise DgtdInputError("with gamma = 1 every state must reach a terminal state, or its return is unbounded")
    if not dependent_features and np.linalg.matrix_rank(Phi) < Phi.shape[1]:
        raise DgtdInputError(
            f"Phi ({Phi.shape[0]} x {Phi.shape[1]}) does not have full column rank "
            f"(rank {np.linalg.matrix_rank(Phi)}); remove features that are linear combinations of others"
        )


NUMBERS = (1e-100, 1e100)  # |phi(s)|^2 and |r| within these: their products and squares stay in float64's range


def _check_range(R, Phi) -> None:
    """Features and rewards whose squares and products float64 holds: beyond, the errors and steps come out NaN."""
    with np.errstate(over="ignore", under="ignore"):
        phi2 = float((Phi**2).sum(axis=1).max()) if Phi.size else 1.0
        r = float(np.abs(R).max()) if R.size else 0.0
    if not np.isfinite(phi2) or phi2 > NUMBERS[1]:
        raise DgtdInputError(f"Phi's features are too large (max |phi(s)|^2 = {phi2:.3g}); scale them to about 1")
    if phi2 < NUMBERS[0]:
        raise DgtdInputError(f"Phi's features are too small (max |phi(s)|^2 = {phi2:.3g}); scale them to about 1")
    if not np.isfinite(r) or r > NUMBERS[1]:
        raise DgtdInputError(f"the rewards are too large (max |r| = {r:.3g}); scale them (the values scale with them)")


def _sampling_model(P, R, P_sample, ratio, R_sample) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(P_sample (S, A, S), ratio (S, A), R_sample (N, S, A)): the behaviour's sampling model, checked to reproduce P
    and R; on-policy (one action, ratio 1) where none is given."""
    S = P.shape[0]
    if P_sample is None:
        P_sample, ratio, R_sample = P[:, None, :], np.ones((S, 1)), R[:, :, None]
    P_sample = _as_float_array("P_sample", P_sample, 3)
    ratio = _as_float_array("ratio", ratio, 2)
    R_sample = _as_float_array("R_sample", R_sample, 3)
    A = P_sample.shape[1]
    if P_sample.shape != (S, A, S) or ratio.shape != (S, A) or R_sample.shape != (R.shape[0], S, A):
        raise DgtdInputError(
            f"sampling model shapes disagree: P_sample {P_sample.shape}, ratio {ratio.shape}, "
            f"R_sample {R_sample.shape} for S={S}, N={R.shape[0]}"
        )
    check_stochastic("the behaviour sampling model", P_sample)
    if np.any(ratio < 0):
        raise DgtdInputError("importance ratios must be >= 0")
    beta = P_sample.sum(axis=2)
    if not np.allclose(np.einsum("sat,sa->st", P_sample, ratio), P, atol=1e-8):
        raise DgtdInputError(
            "the sampling model does not reproduce P: sum_a beta(a|s) P(s,a,s') ratio(s,a) must equal P(s,s')"
        )
    if not np.allclose(np.einsum("sa,nsa->ns", beta * ratio, R_sample), R, atol=1e-8 * max(1.0, np.abs(R).max())):
        raise DgtdInputError("the sampling model does not reproduce R: sum_a pi(a|s) R_sample(i,s,a) must equal R(i,s)")
    return P_sample, ratio, R_sample


def _transition_rewards(R_transition, P_sample, R_sample) -> np.ndarray:
    """r_i(s, a, s') (N, S, A, S), checked to average to R_sample over the next state."""
    N, S, A = R_sample.shape
    R_transition = _as_float_array("R_transition", R_transition, 4)
    if R_transition.shape != (N, S, A, S):
        raise DgtdInputError(f"R_transition must have shape (N, S, A, S) = {(N, S, A, S)}, got {R_transition.shape}")
    beta = P_sample.sum(axis=2)
    P_sa = np.divide(P_sample, beta[:, :, None], out=np.zeros_like(P_sample), where=beta[:, :, None] > 0)
    if not np.allclose(
        np.einsum("sat,nsat->nsa", P_sa, R_transition)[:, beta > 0],
        R_sample[:, beta > 0],
        atol=1e-8 * max(1.0, np.abs(R_sample).max()),
    ):
        raise DgtdInputError("R_sample must be the expectation of R_transition over the next state")
    return R_transition


def _sigma(sigma, R, R_sample, R_transition, signed_rewards: bool, reward_noise: str) -> float:
    """The rewards' bound sigma (the largest |mean reward| where not given), checked against the rewards' signs."""
    if not signed_rewards and (np.any(R < 0) or np.any(R_sample < 0)):
        raise DgtdInputError("rewards must be >= 0 (the paper's rewards lie in [0, sigma]); shift them by a constant")
    r_max = float(
        max(np.abs(R).max(), np.abs(R_sample).max(), 0.0 if R_transition is None else np.abs(R_transition).max())
    )
    if sigma is None:
        sigma = r_max if r_max > 0 else 1.0
    sigma = float(sigma)
    if not np.isfinite(sigma):
        raise DgtdInputError(f"sigma must be a finite number (the rewards' bound, at least {r_max:g}), got {sigma}")
    if sigma <= 0 or sigma < r_max - 1e-12:
        raise DgtdInputError(f"sigma must be positive and at least the largest mean reward {r_max:g}, got {sigma}")
    if signed_rewards and reward_noise not in ("none", "transition"):
        raise DgtdInputError(
            "reward noise draws rewards in [0, sigma]; a problem with signed rewards needs reward_noise='none'"
        )
    return sigma
