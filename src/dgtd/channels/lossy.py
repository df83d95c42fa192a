"""Lost messages: each message on arc j -> i is lost with its own probability, independently of everything else.

The losses of edge e's two arcs at step k are a pair of uniforms keyed by (seed, arc loss, e, k) (`dgtd.streams`),
drawn whether or not the link is up, so that a seed's draws do not depend on the other seeds, on the block size, on
the backend or on which rank draws them, and the samples are those of a run without loss: a loss of 0 delivers
exactly what `Perfect` delivers.

A lost message leaves agent i with the neighbours it did hear: i may hear j while j misses i, so the mean Laplacian
of what is heard, E[L(k)]_ij = -P(i hears j), is no longer symmetric (`mean_laplacian`), nor is the mean Metropolis
mixing (`mean_metropolis`). Every communicating method here then weights agent i's reward by the left null vector
of its mean mixing Laplacian (`dgtd.problems.exact.agent_weights`; docs/links.md derives it), and converges to the
w* of those weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, NamedTuple

import numpy as np

from dgtd.channels.arcs import Arcs
from dgtd.channels.base import counted
from dgtd.channels.inbox import Inbox
from dgtd.errors import DgtdInputError
from dgtd.files import text_of
from dgtd.streams import ARC_BURST_START, ARC_LOSS, seed_keys


def arc_uniforms(keys: np.ndarray, purpose: int, step: int, arcs: Arcs) -> np.ndarray:
    """One uniform per arc (B, 2E) of each seed (``keys`` (B,)) at ``step``, keyed by the agents its link joins
    (`Arcs.uniforms`), so that whoever holds the arc draws it."""
    return arcs.uniforms(keys, purpose, step)


class LinkState(NamedTuple):
    """`Lossy`'s state, per seed: the counts of messages and bits it delivered (B,), the seed's key (B,) its draws
    are keyed by (`dgtd.streams`), the step (B,) it is at, and each arc's state where links have one (B, 2E: 1 while
    a bursty link is in its losing state; else B, 0)."""

    messages: np.ndarray
    bits: np.ndarray
    keys: np.ndarray
    step: np.ndarray
    links: np.ndarray


@dataclass(frozen=True, eq=False)
class Lossy:
    """Arc a (`Arcs`: 2e from v to u, 2e + 1 from u to v of edge e = {u, v}) loses each message it carries with
    probability ``loss[a]``; every message of a step travels together, so they are lost together.

    With ``burst`` = L, losses come in bursts (the Gilbert-Elliott model with a losing and a delivering state): each
    arc is a two-state Markov chain that leaves its losing state with probability 1 / L at each step (bursts of mean
    length L) and enters it with probability loss / (L (1 - loss)), so that it loses a fraction ``loss`` of the
    steps in the long run, as without bursts; the chain starts in its stationary law. Each step draws one uniform per
    arc either way (`arc_uniforms`): the move of its chain, or whether its message is lost."""

    loss: np.ndarray  # (2E,) in [0, 1)
    burst: float | None = None
    reweight: bool = False
    name: ClassVar[str] = "lossy"
    draws: ClassVar[bool] = True
    holds: ClassVar[bool] = False

    def __post_init__(self):
        if self.burst is None:
            return
        L = float(self.burst)
        worst = float(np.max(self.loss / (1.0 - self.loss))) if self.loss.size else 0.0
        if not np.isfinite(L) or L < max(1.0, worst * (1 - 1e-12)):
            raise DgtdInputError(
                f"burst: the mean burst length must be at least 1 and at least loss / (1 - loss) ({worst:.4g} here), "
                f"so that the long-run loss stays the one asked; got {self.burst}"
            )

    @property
    def arc_weights(self) -> np.ndarray:
        """1 / (1 - loss_a): with ``reweight``, agent i weighs what it hears from j by the inverse of its probability
        of hearing it, so that the mean Laplacian of what is heard is the network's own, symmetric one again and the
        methods that mix with it converge to w* (inverse-probability weighting; docs/links.md). An agent needs its
        in-links' loss rates, which it can count."""
        return 1.0 / (1.0 - self.loss)

    @property
    def enter(self) -> np.ndarray:
        """P(an arc's chain enters its losing state at a step), (2E,)."""
        assert self.burst is not None, "only links with bursts enter a losing state"
        return np.minimum(self.loss / (float(self.burst) * (1.0 - self.loss)), 1.0)

    def init(self, seeds: int, arcs: Arcs, seed: int = 0) -> LinkState:
        """Counts at zero, seed k's key (k = 0 .. seeds - 1 of base seed ``seed``), step 0, and with bursts each arc's
        chain drawn from its stationary law."""
        keys = seed_keys(seed, range(seeds))
        links = np.zeros((seeds, 0), np.uint8)
        if self.burst is not None:
            links = (arc_uniforms(keys, ARC_BURST_START, 0, arcs) < arcs.of_arcs(self.loss)).astype(np.uint8)
        return LinkState(np.zeros(seeds), np.zeros(seeds), keys, np.zeros(seeds, np.int64), links)

    def deliver(self, state: LinkState, arcs: Arcs, sent: dict, up: np.ndarray | None):
        """(the step's `Inbox`, the new state): arcs of the edges up (B, E) (None: every edge) that keep the message."""
        B = next(iter(sent.values())).shape[0] if sent else state.messages.shape[0]
        kept, links = self.arcs_up(state, arcs, up, B)
        heard = kept.astype(np.float64)
        weights = arcs.of_arcs(self.arc_weights) if self.reweight else None
        state = counted(state, heard.sum(axis=1), len(sent), sum(x.shape[-1] for x in sent.values()))
        return Inbox(arcs, sent, heard, weights=weights), state._replace(links=links, step=state.step + 1)

    def share(self, arc_ids: np.ndarray, agents: np.ndarray) -> Lossy:
        """Each of the arcs ``arc_ids``' own loss probability (`dgtd.channels.base.Channel.share`)."""
        return Lossy(self.loss[arc_ids], self.burst, self.reweight)

    def mean_mixing(self, network, arcs: Arcs, mixing: str):
        """E[L(k)] of what is heard (`mean_laplacian`), or of its Metropolis mixing (`mean_metropolis`); with
        ``reweight`` the network's own mean Laplacian (E[c_ij heard_ij] = p_e: symmetric again)."""
        if mixing == "metropolis":
            return mean_metropolis(network, self.loss, arcs)
        if self.reweight:
            return network.mean_laplacian()
        return mean_laplacian(network, self.loss, arcs)

    def arcs_up(self, state, arcs: Arcs, up: np.ndarray | None, B: int):
        """(the arcs that carry a message at this step (B, 2E): their edge up (B, E; None: every edge) and their
        message kept; the links' new states), from one uniform per arc; ``state`` a `LinkState`, or any state with
        its keys, step and links (`dgtd.channels.Imperfect`'s)."""
        links = state.links
        if self.burst is None and not self.loss.any():  # nothing lost: the draws, keyed, change nothing else
            kept = np.ones((B, arcs.n_arcs), bool)
        elif self.burst is None:
            kept = arc_uniforms(state.keys, ARC_LOSS, int(state.step[0]), arcs) >= arcs.of_arcs(self.loss)
        else:
            u = arc_uniforms(state.keys, ARC_LOSS, int(state.step[0]), arcs)
            losing = np.where(links == 1, u >= 1.0 / float(self.burst), u < arcs.of_arcs(self.enter))
            links, kept = losing.astype(np.uint8), ~losing
        return arcs.up(up, B) & kept, links

    def describe(self) -> str:
        lo, hi = float(self.loss.min()), float(self.loss.max())
        what = f"each message lost with probability {lo:g}" if lo == hi else f"messages lost with p in [{lo:g}, {hi:g}]"
        what += "" if self.burst is None else f", in bursts of mean length {float(self.burst):g}"
        return what + ("; what is heard weighted by 1 / (1 - loss)" if self.reweight else "")


def loss_per_arc(loss, arcs: Arcs) -> np.ndarray:
    """The loss probability of every arc (2E,) from one probability (every arc), one per agent (the probability
    that agent i misses each message sent to it: a list of N), or a file of 'i j p' lines (agent i misses each
    message from its neighbour j with probability p; arcs not named lose nothing). Checked: each p in [0, 1)."""
    N = arcs.n_agents
    if isinstance(loss, str) and not _is_number(loss):
        per_arc = _loss_file(loss, arcs)
    else:
        values = [float(x) for x in loss.split(",")] if isinstance(loss, str) else loss
        values = np.atleast_1d(np.asarray(values, dtype=np.float64))
        if values.size == 1:
            per_arc = np.full(arcs.n_arcs, values[0])
        elif values.size == N:
            per_arc = values[arcs.dst]
        else:
            raise DgtdInputError(
                f"loss: give one probability, or one per agent ({N} here: the probability that agent i misses each "
                f"message sent to it), or a file of 'i j p' lines; got {values.size} values"
            )
        _check_probabilities(values, "loss")
    return per_arc


def _is_number(text: str) -> bool:
    try:
        [float(x) for x in text.split(",")]
    except ValueError:
        return False
    return True


def _check_probabilities(p: np.ndarray, where: str) -> None:
    bad = ~np.isfinite(p) | (p < 0) | (p >= 1)
    if bad.any():
        raise DgtdInputError(
            f"{where}: a loss probability must lie in [0, 1) (1 would cut the link for good), got {p[bad][0]:g}"
        )


def _loss_file(path: str, arcs: Arcs) -> np.ndarray:
    file = Path(path)
    if not file.is_file():
        raise DgtdInputError(f"loss {path!r} is neither a probability, a list of them, nor a file of 'i j p' lines")
    arc_of = {(int(d), int(s)): a for a, (d, s) in enumerate(zip(arcs.dst, arcs.src))}
    per_arc = np.zeros(arcs.n_arcs)
    for n, line in enumerate(text_of(file).splitlines(), 1):
        words = line.split("#")[0].split()
        if not words:
            continue
        try:
            i, j, p = int(words[0]), int(words[1]), float(words[2])
            if len(words) != 3:
                raise ValueError
        except (ValueError, IndexError):
            raise DgtdInputError(f"{path}, line {n}: expected 'i j p' (agent i misses j's messages w.p. p)") from None
        if (i, j) not in arc_of:
            raise DgtdInputError(f"{path}, line {n}: agents {i} and {j} are not linked in the network's graph")
        _check_probabilities(np.array([p]), f"{path}, line {n}")
        per_arc[arc_of[(i, j)]] = p
    return per_arc


def delivery(network, loss: np.ndarray, arcs: Arcs) -> np.ndarray:
    """P(arc a delivers at a step) (2E,): its edge up and its message kept."""
    return np.repeat(np.asarray(network.p, dtype=np.float64), 2) * (1.0 - loss)


def mean_laplacian(network, loss: np.ndarray, arcs: Arcs) -> np.ndarray:
    """E[L(k)] of what is heard, (N, N): row i sums P(i hears j) (x_i - x_j) over its neighbours j; asymmetric when
    i and j lose each other's messages with different probabilities."""
    N = arcs.n_agents
    q = delivery(network, loss, arcs)
    L = np.zeros((N, N))
    np.add.at(L, (arcs.dst, arcs.src), -q)
    np.add.at(L, (arcs.dst, arcs.dst), q)
    return L


def poisson_binomial(p: np.ndarray) -> np.ndarray:
    """pmf (M, K + 1) of each row's sum of independent Bernoulli(p_k), ``p`` (M, K) (a row padded with zeros has the
    pmf of its other entries, followed by zeros)."""
    pmf = np.zeros((p.shape[0], p.shape[1] + 1))
    pmf[:, 0] = 1.0
    for k in range(p.shape[1]):
        pk = p[:, k : k + 1]
        pmf[:, 1 : k + 2] = pmf[:, : k + 1] * pk + pmf[:, 1 : k + 2] * (1 - pk)
        pmf[:, 0] *= 1 - pk[:, 0]
    return pmf


METROPOLIS_WORK = 1 << 22  # numbers a batch of arcs' Poisson-binomial laws holds at once (`mean_metropolis`)


def mean_metropolis(network, loss: np.ndarray, arcs: Arcs, sparse: bool = False):
    """E[L_W(k)], (N, N) (scipy CSR with ``sparse``), of the Metropolis mixing of what is heard, I - W(k) with
    W_ij = 1 / (1 + max(d_i, d_j)) over the messages i heard from j (`dgtd.channels.Inbox.metropolis`), d_i the
    number i heard. Exact: given that arc j -> i delivers, d_i - 1 and d_j are sums of independent arc events over
    disjoint edges (d_j's includes i -> j, given the edge up), so E[W_ij] = P(j -> i delivers)
    E[1 / (1 + max(1 + X_i, B + X_j))] over their Poisson-binomial laws. The arcs are taken in batches of the same
    largest degree, each law one row of an array: O(sum over arcs of degree^2), no N x N array unless asked."""
    N = arcs.n_agents
    q = delivery(network, loss, arcs)
    keep = 1.0 - loss
    degree = np.bincount(arcs.dst, minlength=N)
    into = np.argsort(arcs.dst, kind="stable")  # the arcs into each agent, in arc order, from first[i]
    first = np.concatenate([[0], np.cumsum(degree)[:-1]])
    width = np.maximum(degree[arcs.dst], degree[arcs.src])
    value = np.zeros(arcs.n_arcs)
    for K in np.unique(width).tolist():
        batch, size = np.flatnonzero(width == K), max(1, METROPOLIS_WORK // (K + 1) ** 2)
        for a in np.split(batch, np.arange(size, batch.size, size)):
            back = a ^ 1  # the other arc of the same edge: i -> j
            x = poisson_binomial(_others(q, into, first, degree, arcs.dst[a], a, K))
            y = poisson_binomial(np.hstack([_others(q, into, first, degree, arcs.src[a], back, K), keep[back, None]]))
            d_i, d_j = 1 + np.arange(x.shape[1]), np.arange(y.shape[1])  # y's last column: + B, i -> j kept
            inv = 1.0 / (1.0 + np.maximum(d_i[:, None], d_j[None, :]))
            value[a] = q[a] * np.einsum("mx,xy,my->m", x, inv, y)
    rows, cols = np.concatenate([arcs.dst, np.arange(N)]), np.concatenate([arcs.src, np.arange(N)])
    entries = np.concatenate([-value, np.bincount(arcs.dst, value, N)])
    from scipy.sparse import coo_matrix

    L = coo_matrix((entries, (rows, cols)), shape=(N, N)).tocsr()
    return L if sparse else L.toarray()


def _others(q: np.ndarray, into: np.ndarray, first: np.ndarray, degree: np.ndarray, agent, arc, K: int) -> np.ndarray:
    """(M, K): the delivery probabilities of the arcs into each ``agent`` other than ``arc``, padded with zeros."""
    slot = np.arange(K)[None, :]
    at = into[np.minimum(first[agent][:, None] + slot, into.size - 1)]
    return np.where((slot < degree[agent][:, None]) & (at != arc[:, None]), q[at], 0.0)
