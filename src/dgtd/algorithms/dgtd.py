"""Algorithm 1 of the paper (section 7): the primal-dual distributed GTD method.

State is four arrays (B, N, q) for B seeds and N agents: theta, v, mu (minimised) and w (maximised) of the
Lagrangian of section 5 (with the consensus penalty -(kappa/2) w^T bar-L w). One step uses one sample per
agent and the neighbour sums (L(k) x)_i over the links up at step k, and every quantity on the right-hand side is
taken at step k (Jacobi form, as in Algorithm 1). The signs follow the Lagrangian and the appendix, not the KKT
equations of section 6, whose w-gradient has its signs flipped.

What each agent sends (`DGTD.messages`): w_i and v_i + mu_i, two vectors per link and step where the paper's
Algorithm 1 (lines 7-8) sends three (w_i, v_i, mu_i). The update uses (L(k) v)_i and (L(k) mu)_i only through their
sum, and (L v)_i + (L mu)_i = (L (v + mu))_i exactly in real arithmetic (in floating point the two differ by a
rounding, ~1e-16 relative); message counts count two.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.algorithms.base import FixedPoint, StepSizes, check_nonnegative, clip, zeros
from dgtd.algorithms.stepsizes import describe as describe_steps
from dgtd.errors import DgtdInputError
from dgtd.fields import option
from dgtd.samples import Sample

BOX_NAMES = ("theta", "v", "mu", "w")


class DGTDParams(NamedTuple):
    kappa: float
    rho: float
    b_theta: float  # the projection boxes' half-widths (Algorithm 1 line 9; inf: none)
    b_v: float
    b_mu: float
    b_w: float


@dataclass(frozen=True)
class DGTD(StepSizes):
    """Hyperparameters of Algorithm 1.

    - ``alpha0``, ``beta``, ``schedule``: step sizes alpha_k (see `dgtd.algorithms.stepsizes`).
    - ``kappa`` >= 0: weight of the consensus term -(kappa/2) w^T bar-L w of the Lagrangian (section 5).

    The defaults, alpha_k = 10 / sqrt(k + 1000) and kappa = 3, are the fastest to 1 % value error of the tail
    average found on paper-example-1, boyan and garnet (docs/benchmarks.md): the offset 1000 keeps the first
    steps small enough that the consensus part of Algorithm 1 does not swing the iterates between the boxes, and
    kappa = 3 ties the agents closer than the paper's 1 (the paper's Example 1 keeps the paper's 10 / sqrt(k + 100)
    and kappa = 1). They suit features of unit scale (|phi(s)|^2 up to a few); with larger feature vectors lower
    alpha0 in proportion (the random-MDP tasks, |phi|^2 ~ 70, use 0.3).
    - ``rho`` >= 0: the regulariser (rho/2)|mu|^2 - (rho/2)|w|^2 (the remark after Proposition 7).
    - ``box_scale``: projection boxes are C = B_{c + beta_c} with beta_c = (box_scale - 1) c and c the bounds of
      Lemma 2 (section 6); ``boxes`` (theta, v, mu, w half-widths) overrides them.

    Example::

        >>> from dgtd.algorithms import DGTD
        >>> DGTD(alpha0=1.0, kappa=0.5).messages
        ('w', 'vmu')
    """

    alpha0: float = 10.0
    beta: float = 1000.0
    kappa: float = field(default=3.0, metadata=option("Weight of the consensus term of the Lagrangian (section 5)."))
    rho: float = field(default=0.0, metadata=option("Regulariser (rho/2)|mu|^2 - (rho/2)|w|^2 (0 = none)."))
    box_scale: float = field(
        default=2.0,
        metadata=option(
            "Projection boxes C = B_{c + beta_c}, beta_c = (box_scale - 1) c, c the bounds of Lemma 2 (section 6)."
        ),
    )
    boxes: tuple[float, float, float, float] | None = field(
        default=None,
        metadata=option("The projection boxes' half-widths, instead of box_scale's.", metavar="THETA,V,MU,W"),
    )

    name: ClassVar[str] = "dgtd"
    description: ClassVar[str] = "the paper's primal-dual distributed GTD (Algorithm 1)"
    color: ClassVar[str] = "#d62728"
    messages: ClassVar[tuple[str, ...]] = ("w", "vmu")  # w_i, and v_i + mu_i (see the module's docstring)

    def __post_init__(self):
        super().__post_init__()
        check_nonnegative("kappa", self.kappa)
        check_nonnegative("rho", self.rho)
        if not (np.isfinite(self.box_scale) and self.box_scale > 1.0):
            raise DgtdInputError(
                f"box_scale must be > 1 (the boxes must contain the saddle point), got {self.box_scale}"
            )
        # v and mu may be pinned at 0 (no links: their bounds of Lemma 2 are 0); theta and w may not
        if self.boxes is not None and (
            len(self.boxes) != 4 or not all(b >= 0 for b in self.boxes) or not (self.boxes[0] > 0 and self.boxes[3] > 0)
        ):
            raise DgtdInputError(
                "boxes must be four half-widths (theta, v, mu, w), theta and w positive, v and mu "
                f">= 0, got {self.boxes}"
            )

    reads: ClassVar = (("phi", "theta"), ("phi", "w"), ("phi_next", "w"))
    Params: ClassVar = DGTDParams

    def params(self) -> DGTDParams:
        boxes = (np.inf,) * 4 if self.boxes is None else self.boxes
        return DGTDParams(float(self.kappa), float(self.rho), *(float(b) for b in boxes))

    def init(self, seeds: int, agents: int, features: int) -> DGTDState:
        """Algorithm 1 line 3: all variables start at zero."""
        return DGTDState(*zeros(seeds, agents, features, 4))

    @staticmethod
    def transmit(x):
        """w_i and v_i + mu_i at step k: all that the neighbours' updates read of agent i."""
        theta, v, mu, w = x
        return w, v + mu

    @staticmethod
    def coefficients(p, dots, r, ratio, gamma):
        """Line 7's theta direction is phi c_theta, line 8's TD part of w's is ratio phi^T theta (phi - gamma phi')."""
        phi_theta, phi_w, phin_w = dots
        c_theta = phi_theta + ratio * (phi_w - gamma * phin_w - r)
        return c_theta, ratio * phi_theta

    @staticmethod
    def terms(p, phi, phi_next, c, gamma):
        """The sample's parts of the theta and w directions: phi c_theta and ratio phi^T theta (phi - gamma phi')."""
        c_theta, ratio_phi_theta = c
        return phi * c_theta, ratio_phi_theta * (phi - gamma * phi_next)

    @staticmethod
    def feature(p, x, heard, d, steps):
        """One step of Algorithm 1: lines 7-8 (descent on theta, v, mu; ascent on w, `gradient`) and line 9
        (projection onto the max-norm balls C_theta, C_v, C_mu, C_w of half-widths ``boxes``; none while None)."""
        theta, v, mu, w = x
        (alpha,) = steps
        g_theta, g_v, g_mu, g_w = gradient(p, x, heard, d)
        return (
            clip(theta - alpha * g_theta, p.b_theta),
            clip(v - alpha * g_v, p.b_v),
            clip(mu - alpha * g_mu, p.b_mu),
            clip(w + alpha * g_w, p.b_w),
        )

    def fixed_point(self, moments, mean_laplacian, w_star: np.ndarray) -> FixedPoint:
        """The saddle point of the Lagrangian (section 6, Proposition 4; with rho > 0 the regularised one, each
        agent's own w): its w is measured against, and theta* and mu* are reported."""
        from dgtd.problems import exact

        rho = self.rho
        if moments.b.shape[0] * w_star.shape[0] > exact.REGULARISED_MAX:
            rho = 0.0  # too large to solve densely: report the unregularised saddle point, the problem's own
        if not exact.is_symmetric(mean_laplacian):  # messages lost more one way than the other
            if rho > 0:
                raise DgtdInputError(
                    "DGTD with rho > 0 over links that lose messages is not supported: its fixed point is not "
                    "computed; use rho = 0"
                )
            saddle = exact.directed_saddle_point(moments, mean_laplacian)
            w_star = saddle.w[0]
        else:
            saddle = exact.saddle_point(moments, mean_laplacian, self.kappa, rho)
        return FixedPoint(
            saddle.w if rho > 0 else w_star[None, :],
            {
                "theta_star": saddle.theta,
                "v_star": saddle.v,
                "mu_star": saddle.mu,
                "kkt_residuals": exact.kkt_residuals(moments, mean_laplacian, self.kappa, rho, saddle),
            },
        )

    def prepare(self, moments, network, fixed: FixedPoint) -> tuple:
        """DGTD projecting onto the boxes it resolves here (`resolve_boxes`), and the boxes it uses."""
        saddle = (fixed.report["theta_star"], fixed.report["v_star"], fixed.report["mu_star"], fixed.w)
        boxes, grown = resolve_boxes(self, moments, network, saddle)
        return replace(self, boxes=boxes), {
            "boxes": dict(zip(BOX_NAMES, boxes)),
            "boxes_grown": {name: {"lemma": lemma, "used": used} for name, (lemma, used) in grown.items()},
        }

    def diagnostics(self, state: DGTDState, moments, mean_laplacian) -> dict:
        """|gradient of the Lagrangian|_inf at the last iterate, per variable: how far from a KKT point it is."""
        from dgtd.problems import exact

        grads = exact.lagrangian_gradient(moments, mean_laplacian, self.kappa, self.rho, *state)
        return {"kkt_residuals_last": {name: float(np.abs(g).max()) for name, g in zip(BOX_NAMES, grads)}}

    def describe(self) -> str:
        return (
            f"Algorithm 1: alpha_k = {describe_steps(self.schedule, self.alpha0, self.beta)}, kappa {self.kappa:g}, "
            f"rho {self.rho:g}"
        )


class DGTDState(NamedTuple):
    theta: np.ndarray
    v: np.ndarray
    mu: np.ndarray
    w: np.ndarray


def gradient(p: DGTDParams, x, heard, d):
    """Stochastic gradient of the Lagrangian at step k, (g_theta, g_v, g_mu, g_w), from what the agent heard (``heard``:
    (L(k) w)_i and (L(k) v)_i + (L(k) mu)_i) and the sample's directions ``d`` (`DGTD.terms`).

    Its expectation over samples and links is the gradient of the Lagrangian of section 5 plus the rho terms
    (`dgtd.problems.exact.lagrangian_gradient`, the test of `direction`); the importance ratio multiplies the terms
    that come from the TD error, as in off-policy GTD.
    """
    theta, v, mu, w = x
    Lw, Lvmu = heard
    d_theta, d_w = d
    # Line 7, theta: phi phi^T theta + ratio (phi phi^T w - gamma phi phi'^T w - phi r)
    g_theta = d_theta
    # Line 7, v: v - (|N_i(k)| w_i - sum_j w_j) = v - (L(k) w)_i
    g_v = v - Lw
    # Line 8, mu: descent on -(L(k) w)_i, plus rho mu
    g_mu = -Lw + p.rho * mu
    # Line 8, w: ascent on ratio (phi - gamma phi') phi^T theta - (L v)_i - (L mu)_i - kappa (L w)_i - rho w
    g_w = d_w - Lvmu - p.kappa * Lw - p.rho * w
    return g_theta, g_v, g_mu, g_w


def direction(state: DGTDState, sample: Sample, inbox, kappa: float, rho: float):
    """`gradient` of every seed and agent, all (B, N, q), from a step's sample and what each agent heard (the messages
    w and vmu = v + mu of `DGTD.sends`)."""
    algorithm = DGTD(kappa=kappa, rho=rho)
    heard = (inbox.laplacian("w"), inbox.laplacian("vmu"))
    return gradient(algorithm.params(), tuple(state), heard, algorithm.directions(state, sample))


def resolve_boxes(algorithm: DGTD, moments, network, saddle: tuple) -> tuple:
    """(projection half-widths (theta, v, mu, w), {name: (the lemma's box, the box used)} for the boxes grown), for the
    saddle point ``saddle`` (theta*, v*, mu*, w*), each (N, q).

    The algorithm's own boxes are used as given, and refused if one excludes the saddle point. Otherwise each box
    is box_scale x the bound of Lemma 2 (section 6), grown to box_scale x |x*|_inf where the bound is smaller than
    |x*|_inf: the lemma assumes on-policy sampling, and off-policy w* can exceed it, where the iterates could never
    reach w*. Without a model (estimated moments) there is no Lemma 2, and box_scale x |x*| could pin a variable
    whose saddle value is near 0 (v* = 0 always): no projection, which only bounds the early transient.
    """
    from dgtd.problems import exact

    needed = tuple(float(np.abs(x).max()) for x in saddle)
    if algorithm.boxes is not None:
        boxes = tuple(float(b) for b in algorithm.boxes)
        for name, box, x in zip(BOX_NAMES, boxes, needed):
            if box < x:
                raise DgtdInputError(
                    f"the {name} box {box:g} excludes the saddle point (|{name}*|_inf = {x:.6g}), so "
                    f"the iterates could never reach it; give a {name} box of at least "
                    f"{algorithm.box_scale * x:.6g} ({algorithm.box_scale:g} x |{name}*|_inf), or "
                    "leave the boxes to dgtd"
                )
        return boxes, {}
    if not moments.model:
        return (np.inf,) * 4, {}
    max_degree = int(np.bincount(network.base.edges.ravel(), minlength=network.n_nodes).max()) if network.n_edges else 0
    c = exact.lemma_bounds(moments, network.mean_laplacian(sparse=network.n_nodes > exact.DENSE_N), max_degree)
    lemma = tuple(algorithm.box_scale * x for x in (c.theta, c.v, c.mu, c.w))
    boxes = tuple(max(box, algorithm.box_scale * x) for box, x in zip(lemma, needed))
    grown = {name: (a, b) for name, a, b in zip(BOX_NAMES, lemma, boxes) if b > a}
    return boxes, grown
