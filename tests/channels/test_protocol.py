"""The channel protocol (`dgtd.channels.base.Channel`): every link model follows it with a state of its own and its
part over an MPI rank's arcs; a link model of one's own runs through the library's loop, its mean mixing sets the
fixed point, and the compiled backend, which has no twin of it, hands it to the reference with a one-line notice.
Outside the channels, the compiled twins and the config that builds them from options, no module names a link
model."""

from __future__ import annotations

import ast
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, NamedTuple

import numpy as np
import pytest
from numpy.testing import assert_array_equal

import dgtd
from dgtd.algorithms import make_algorithm
from dgtd.backends.compiled import TWINS
from dgtd.channels import CHANNELS, Arcs, Channel, Counts, Imperfect, Inbox, Lossy, Perfect, counted, per_arc_fields
from dgtd.channels.base import copied
from dgtd.graphs import topologies
from dgtd.graphs.random import random_edges
from dgtd.problems import exact

SRC = Path(dgtd.__file__).resolve().parent


def ring5(p=0.7):
    net = random_edges(topologies.ring(5), p)
    return net, Arcs.of(net.base.edges, net.n_nodes)


def examples(arcs: Arcs, N: int) -> dict:
    """One of each registered link model, with parameters that differ per arc and per agent."""
    loss = np.linspace(0.0, 0.5, arcs.n_arcs)
    return {
        "perfect": Perfect(),
        "lossy": Lossy(loss, burst=3.0),
        "imperfect": Imperfect(Lossy(loss), delay=2, wake=np.linspace(0.5, 1.0, N), bits=8),
    }


def test_every_registered_link_model_follows_the_protocol_with_a_state_of_its_own():
    """Each has its compiled twin registered under its name; its state holds the counts and only its own fields: the
    perfect channel's nothing else, the lossy links' no copies."""
    net, arcs = ring5()
    sent = {"x": np.ones((2, 5, 3)), "y": np.ones((2, 5, 1))}
    fields = {}
    for name, channel in examples(arcs, 5).items():
        assert isinstance(channel, Channel) and CHANNELS[name] is type(channel) and TWINS[name] is type(channel)
        state = channel.init(2, arcs, seed=3)
        inbox, after = channel.deliver(copied(state), arcs, sent, np.ones((2, net.n_edges), bool))
        assert type(after) is type(state) and isinstance(inbox, Inbox)
        assert after.messages.sum() > 0 and after.bits.sum() > 0
        fields[name] = set(type(state)._fields)
        for name_, x in per_arc_fields(after).items():  # the fields the MPI runtime cuts and joins by arc
            assert x.shape[:2] == (2, arcs.n_arcs), (name, name_)
    assert fields["perfect"] == {"messages", "bits"}
    for name, channel in examples(arcs, 5).items():  # parameters per arc and agent: checked over their network
        assert dgtd.check_channel(channel, net)["messages"] > 0, name
    assert fields["perfect"] < fields["lossy"] < fields["imperfect"] and "copies" not in fields["lossy"]


def test_a_link_model_s_share_keeps_each_arc_s_and_agent_s_own_parameters():
    """`share` (the MPI part): the arcs' loss and the agents' wake of a rank's arcs and agents, the rest as given."""
    net, arcs = ring5()
    channels = examples(arcs, 5)
    ids, agents = np.array([1, 4, 7]), np.array([0, 3])
    assert channels["perfect"].share(ids, agents) == channels["perfect"]
    lossy = channels["lossy"].share(ids, agents)
    assert_array_equal(lossy.loss, channels["lossy"].loss[ids]) and lossy.burst == 3.0
    imperfect = channels["imperfect"].share(ids, agents)
    assert_array_equal(imperfect.loss, channels["imperfect"].loss[ids])
    assert_array_equal(imperfect.wake, channels["imperfect"].wake[agents])
    assert (imperfect.delay, imperfect.bits) == (2, 8)


@dataclass(frozen=True)
class Downhill:
    """A user's link model: each edge up carries messages from its larger agent to its smaller only (arc 2e of edge
    e = {u, v}, u < v, runs from v to u: `Arcs`)."""

    name: ClassVar[str] = "downhill"
    draws: ClassVar[bool] = False
    holds: ClassVar[bool] = False

    def init(self, seeds, arcs, seed=0):
        return Counts(np.zeros(seeds), np.zeros(seeds))

    def deliver(self, state, arcs, sent, up):
        B = state.messages.shape[0]
        heard = (arcs.up(up, B) & (arcs.arc_ids % 2 == 0)).astype(np.float64)
        numbers = sum(x.shape[-1] for x in sent.values())
        return Inbox(arcs, sent, heard), counted(state, heard.sum(axis=1), len(sent), numbers)

    def share(self, arc_ids, agents):
        return self

    def mean_mixing(self, network, arcs, mixing):
        L = np.zeros((arcs.n_agents, arcs.n_agents))
        downhill = arcs.arc_ids % 2 == 0
        p = np.repeat(np.asarray(network.p, dtype=np.float64), 2) * downhill
        np.add.at(L, (arcs.dst, arcs.src), -p)
        np.add.at(L, (arcs.dst, arcs.dst), p)
        return L

    def describe(self):
        return "messages downhill only"


def test_a_link_model_of_one_s_own_runs_and_its_mean_mixing_sets_the_fixed_point():
    """On a ring of 5 agent 4 is the larger end of both its edges, so it hears no one and every other agent hears it
    down some path: the mean mixing's left null vector is e_4, and DGTD's fixed point is the w* of agent 4's reward
    alone (A w = b_4: docs/links.md), a closed form the run reports. The compiled backend has no twin of this link
    model: it says so in one line and runs it on the reference, with the reference's numbers, bit for bit."""
    sc = dgtd.scenario("paper-example-1")
    net, arcs = ring5()
    alg = make_algorithm("dgtd")
    m = exact.Moments(sc.problem)
    runs = {}
    for backend in ("numpy", "numba"):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            runs[backend] = dgtd.evaluate(
                sc.problem, net, alg, iterations=300, seeds=2, backend=backend, channel=Downhill()
            )
        notices = [str(w.message) for w in caught if "no compiled twin" in str(w.message)]
        assert len(notices) == (backend == "numba"), notices
    assert_array_equal(runs["numpy"].w_last, runs["numba"].w_last)
    pi = exact.agent_weights(Downhill().mean_mixing(net, arcs, "laplacian"))
    assert np.allclose(pi, np.eye(5)[4], atol=1e-12)
    want = exact.fixed_point(m, m.b[4])
    assert np.allclose(runs["numpy"].fixed.w[0], want, rtol=1e-10, atol=1e-12)
    assert exact.value_error(m, want[None], exact.w_star(m))[0] > 0.05  # not w*: the test can tell
    assert runs["numpy"].info["messages"].sum() > 0


LINK_MODELS = {name for name in CHANNELS} | {cls.__name__ for cls in CHANNELS.values()} - {"Perfect"}
ALLOWED = ("channels/", "backends/compiled/", "config.py")  # the link models, their twins, and options -> models


def test_no_module_outside_the_channels_names_a_link_model():
    """Code that dispatches on which link model runs reads the protocol (``draws``, ``holds``, ``share``,
    ``mean_mixing``) instead: a new link model is its own file, its twin and its options. (`Perfect` is the default
    wherever no channel is given, and may be named.)"""
    named = []
    for path in sorted(SRC.rglob("*.py")):
        where = path.relative_to(SRC).as_posix()
        if where.startswith(ALLOWED[:2]) or where == ALLOWED[2]:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.Name | ast.Attribute):
                names = [node.id if isinstance(node, ast.Name) else node.attr]
            elif isinstance(node, ast.ImportFrom):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.Compare):  # a channel's name compared with
                names = [c.value for c in [node.left, *node.comparators] if isinstance(c, ast.Constant)]
            named += [f"{where}:{node.lineno} {n}" for n in names if n in LINK_MODELS - {"perfect"}]
    assert not named, named


def test_beyond_the_agents_whose_fixed_point_is_solved_a_link_model_s_own_is_said_unknown():
    """Past `dgtd.problems.exact.DENSE_N` agents the mean mixing is not formed densely: the perfect links' fixed point
    is still w* (their mixing is symmetric), but any other link model's, a user's included, is said not computed
    rather than taken to be w*."""
    from dgtd.run.loop import fixed_point_unknown

    net = random_edges(topologies.ring(exact.DENSE_N + 1), 0.5)
    alg = make_algorithm("dgtd")
    assert not fixed_point_unknown(net, Perfect(), alg)
    assert fixed_point_unknown(net, Downhill(), alg) and fixed_point_unknown(net, Lossy(np.zeros(2 * net.n_edges)), alg)
    assert not fixed_point_unknown(ring5()[0], Downhill(), alg)


class PlainCounts(NamedTuple):
    """A state as the README describes one: a NamedTuple of the counts, and nothing else (no ``copy``)."""

    messages: np.ndarray
    bits: np.ndarray


@dataclass(frozen=True)
class PlainDownhill(Downhill):
    """`Downhill` with a state of its own, as a user writes it from the README."""

    name: ClassVar[str] = "plain-downhill"

    def init(self, seeds, arcs, seed=0):
        return PlainCounts(np.zeros(seeds), np.zeros(seeds))


def test_a_link_model_as_the_readme_describes_runs_without_an_undocumented_copy_and_passes_check_channel():
    """Its state a plain NamedTuple: runs failed (`channel_state.copy()`) until a ``copy`` method was added. It runs
    on the reference as `Downhill` does, to the same numbers, and `dgtd.check_channel` passes it."""
    sc = dgtd.scenario("paper-example-1")
    net, _ = ring5()
    alg = make_algorithm("dgtd")
    plain, counted_ = (
        dgtd.evaluate(sc.problem, net, alg, iterations=200, seeds=2, backend="numpy", channel=c)
        for c in (PlainDownhill(), Downhill())
    )
    assert_array_equal(plain.w_last, counted_.w_last)
    report = dgtd.check_channel(PlainDownhill())
    assert report["arcs"] > 0 and report["steps"] > 0


@dataclass(frozen=True)
class NoBits(Downhill):
    def init(self, seeds, arcs, seed=0):
        return NamedTupleWithout(np.zeros(seeds))


class NamedTupleWithout(NamedTuple):
    messages: np.ndarray


@dataclass(frozen=True)
class OwnGenerator(Downhill):
    def deliver(self, state, arcs, sent, up):
        inbox, new = super().deliver(state, arcs, sent, up)
        inbox.heard = inbox.heard * (np.random.default_rng().random(inbox.heard.shape) < 0.5)  # not keyed
        return inbox, new._replace(messages=state.messages + inbox.heard.sum(axis=1))


@dataclass(frozen=True)
class NotALaplacian(Downhill):
    def mean_mixing(self, network, arcs, mixing):
        return np.eye(arcs.n_agents)


@dataclass(frozen=True)
class WrongHeard(Downhill):
    def deliver(self, state, arcs, sent, up):
        inbox, new = super().deliver(state, arcs, sent, up)
        inbox.heard = inbox.heard[:, :1]
        return inbox, new


@pytest.mark.parametrize(
    "channel, words",
    [
        (NoBits(), "bits"),
        (OwnGenerator(), "other numbers for the same state and input"),
        (NotALaplacian(), "rows of mean_mixing"),
        (WrongHeard(), "heard"),
    ],
    ids=["no bits", "not keyed", "not a Laplacian", "heard of the wrong shape"],
)
def test_check_channel_says_what_a_faulty_link_model_breaks_in_one_line(channel, words):
    with pytest.raises(AssertionError) as caught:
        dgtd.check_channel(channel)
    said = str(caught.value)
    assert words in said and "\n" not in said, said
