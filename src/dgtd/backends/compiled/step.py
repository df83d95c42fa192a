"""Each algorithm's compiled per-agent step, made from its one definition (`dgtd.algorithms.base`), and the helpers
it runs on.

`compiled_step(algorithm, name)` compiles the algorithm's ``coefficients``, ``terms``, ``feature``, ``transmit`` and
``steps`` (and the plain functions they call, `clip` in place of NumPy's) and puts them in one of two templates, which
the driver (`dgtd.backends.compiled.driver`) calls for every learner at every step with the same arguments:

- `_agent`: one agent of a distributed algorithm (or a learner of its own, ``local``): the aggregates of what it heard
  (Laplacian or Metropolis, as the algorithm's ``mixing``), the products it ``reads``, its coefficients, then for each
  feature its directions and its ``feature``, the new state kept and its messages sent;
- `_centralised`: the one learner of a centralised algorithm: the directions of the N transitions summed (on sparse
  features, only where phi(s) or phi(s') is not zero), then for each feature their mean through its ``feature``.

What the step is given: ``p`` the algorithm's `params`; ``own`` the state's fields that are not sent, stacked (K, B,
learners, q), updated in place in rows [k, b, i]; ``sums`` the running sum of the estimates (B, learners, q), to which
the step adds w at step k (as the reference's ``w_sum += estimate(state)`` before ``update``); ``inbox`` what agent i
heard (`dgtd.backends.compiled.channel.Inbox`: the messages of step k, stacked (M, B, N, q) in the order of the
algorithm's ``messages``) and ``out`` the messages it sends at step k + 1, written in rows [m, b, i] (the driver
double-buffers them, so every agent reads its neighbours' values of step k); ``work`` its scratch rows (`PHI`,
`TERMS`), (K, rows, q or more), row ``inbox.at`` its own; ``x`` the step's samples (`transition` gives an
agent's), ``feat`` the features (`Features`); ``b``, ``i``, ``agent`` the seed, the storage row and the agent in it;
``alpha`` the step size; ``q`` the number of features (passed in: computed from a shape inside, LLVM cannot prove the
feature loops' indices in range and leaves them scalar).

The state's arrays are stacked in one array (rather than a tuple of arrays) so that the parallel layout, which numba
cannot hand tuples of arrays, takes them as they are; each array is a contiguous block of its own, and a row's loops
vectorise as over separate arrays. A feature's values go to the algorithm's functions as tuples, loaded and stored
by accessors spelled out for its numbers of fields and messages (`_spelled`), which LLVM keeps in registers.
"""

from __future__ import annotations

import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from numba import njit

from dgtd.algorithms import ALGORITHMS, base
from dgtd.backends.compiled.channel import laplacian, metropolis
from dgtd.backends.compiled.simd import dot

PHI, PHI_NEXT = 0, 1  # an agent's work rows: dense rows of sparse phi(s) and phi(s')
TERMS = 0  # a centralised learner's work rows: its directions summed over the N transitions


def _placeholder(*args):
    """Stands for one of an algorithm's functions in the templates below (`compiled_step` puts the algorithm's own)."""
    raise NotImplementedError("the templates run as compiled by `compiled_step`")


# What the templates `_agent` and `_centralised` call of an algorithm, each compiled copy its own (`compiled_step`):
# its functions, and the accessors spelled out for its numbers of fields, messages, products and directions.
COEFFICIENTS = TERMS_OF = FEATURE = TRANSMIT = STEPS_OF = _placeholder
PRODUCTS = LOAD_STATE = LOAD_HEARD = STORE = LOAD_TERMS = ADD_TERMS = _placeholder
W_AT = (0, 0)  # where w is: own 0 or sent 1, row
M = 0  # messages
METROPOLIS = False  # its mixing: Metropolis weights, or the Laplacian
N_TERMS = 0  # its directions


@dataclass(frozen=True)
class CompiledStep:
    """An algorithm's compiled step: the function the driver inlines, the names of the state's arrays it keeps in
    ``own`` (in that order), whether its inbox needs every agent's count of messages heard (the Metropolis weights
    do), how many work rows it uses, the name its kernels are compiled under and whether they are cached on disk."""

    step: Callable
    own: tuple[str, ...]
    degrees: bool
    work: int
    key: str
    cache: bool = True
    generated: str = ""  # the accessors spelled out for its fields and messages (`source_of`)


def compiled_step(algorithm, name: str, cache: bool = True) -> CompiledStep:
    """The step of ``algorithm``'s class from its one definition, compiled (on first use) under ``name``, its kernels
    cached on disk where ``cache``. It depends on the class only (the hyperparameters are the step's argument ``p``);
    the instance gives the state's fields and the number of directions."""
    cls = type(algorithm)
    space, own, n_terms, generated = algorithm_space(algorithm)
    space["features"] = _in(space, features, "features")  # it reads the constants of the space
    step = _in(space, _centralised if cls.centralised else _agent, f"step_{name}")
    work = TERMS + n_terms if cls.centralised else PHI_NEXT + 1
    return CompiledStep(step, own, cls.mixing == "metropolis", work, name, cache, "\n".join(generated))


def algorithm_space(algorithm) -> tuple[dict, tuple[str, ...], int, list[str]]:
    """(the globals a template of this module runs with for ``algorithm``'s class, the state's fields it keeps to
    itself, its number of directions, the accessors' text): its functions compiled and its accessors spelled out
    (`COEFFICIENTS` ... `N_TERMS` above), for the templates here and the learners'
    (`dgtd.backends.compiled.learner`)."""
    cls = type(algorithm)
    fields = tuple(algorithm.init(1, 1, 1)._fields)
    own = tuple(f for f in fields if f not in cls.messages)
    sent = tuple(f for f in fields if f in cls.messages)
    if fields != own + sent or sent != cls.messages[: len(sent)]:
        raise TypeError(
            f"{cls.name}'s state lists {fields}: what it keeps to itself first, then what it sends, in the order of "
            f"its messages {cls.messages}"
        )
    where = {f: ("own", k) for k, f in enumerate(own)} | {f: ("sent", m) for m, f in enumerate(sent)}
    p = algorithm.params()
    n_terms = len(cls.terms(p, 1.0, 1.0, cls.coefficients(p, (1.0,) * len(cls.reads), 1.0, 1.0, 1.0), 1.0))
    M, state = len(cls.messages), [f"{where[f][0]}[{where[f][1]}, b, i, f]" for f in fields]
    stores = [f"own[{k}, b, i, f] = new[{k}]" for k in range(len(own))]
    stores += [f"out[{m}, b, i, f] = messages[{m}]" for m in range(M)]
    products = [
        f"phi_dot(feat, {'sn' if feature == 'phi_next' else 's'}, {where[x][0]}, ({where[x][1]}, b, i), q)"
        for feature, x in cls.reads
    ]
    terms = [f"work[{TERMS + k}, at, f]" for k in range(n_terms)]
    generated: list[str] = []
    space = dict(
        globals(),
        COEFFICIENTS=_compiled(cls.coefficients),
        TERMS_OF=_compiled(cls.terms),
        FEATURE=_compiled(cls.feature),
        TRANSMIT=_compiled(cls.transmit),
        STEPS_OF=_compiled(cls.steps),
        **{
            name: _spelled(name, cls.name, arguments, lines, generated)
            for name, arguments, lines in (
                ("PRODUCTS", "feat, s, sn, own, sent, b, i, q", [f"return {_tuple(products)}"]),
                ("LOAD_STATE", "own, sent, b, i, f", [f"return {_tuple(state)}"]),
                ("LOAD_HEARD", "L, at, f", [f"return {_tuple([f'L[{m}, at, f]' for m in range(M)])}"]),
                ("STORE", "own, out, b, i, f, new, messages", stores or ["pass"]),
                ("LOAD_TERMS", "work, at, f", [f"return {_tuple(terms)}"]),
                ("ADD_TERMS", "work, at, f, d", [f"{x} += d[{k}]" for k, x in enumerate(terms)] or ["pass"]),
            )
        },
        W_AT=(int(where["w"][0] == "sent"), where["w"][1]),
        M=M,
        METROPOLIS=cls.mixing == "metropolis",
        N_TERMS=n_terms,
    )
    return space, own, n_terms, generated


def _tuple(items: list[str]) -> str:
    return "(" + "".join(f"{x}, " for x in items) + ")"


def _spelled(name: str, owner: str, arguments: str, lines: list[str], generated: list[str]):
    """A function of ``arguments`` with body ``lines``, compiled to be inlined: the loads and stores of a feature's
    values, spelled out for an algorithm's numbers of fields, messages, products and directions, as numba types a tuple
    only from constant indices (a tuple from a column of the stack, ``to_fixed_tuple``, kept the feature loop from
    being vectorised: measured 2 to 2.5 times slower). Its text goes to ``generated`` (`source_of` prints it), and an
    error in it names it and its algorithm (``<dgtd: LOAD_STATE of tdc-tracking>``), not ``<string>``."""
    text = f"def {name}({arguments}):\n    " + "\n    ".join(lines) + "\n"
    generated.append(text)
    space = {"phi_dot": phi_dot}
    exec(compile(text, f"<dgtd: {name} of {owner}>", "exec"), space)
    return njit(inline="always")(space[name])


ALGORITHM_FUNCTIONS = ("coefficients", "terms", "feature", "transmit", "steps")


def source_of(algorithm) -> str:
    """What the compiled backend runs for one learner of ``algorithm`` at one step, as text: where its own functions
    are (file and line: numba inlines them as written, and an error in one names that line), the template the driver
    calls with them in place, and the accessors generated for its fields and messages. None of it is compiled here.

    Example::

        >>> import dgtd
        >>> from dgtd.backends.compiled import source_of
        >>> print(source_of(dgtd.TDC()))  # doctest: +SKIP
    """
    import inspect

    compiled = step_of(algorithm)
    cls = type(algorithm)
    if compiled is None:
        return f"# {cls.name} writes update alone: it runs on the NumPy reference backend, not compiled"
    lines = [f"# The compiled step of {cls.name} ({cls.__module__}.{cls.__qualname__}): its own functions, inlined"]
    for name in ALGORITHM_FUNCTIONS:
        fn = getattr(getattr(cls, name), "__func__", getattr(cls, name))
        code = fn.__code__
        lines.append(f"#   {name}: {code.co_filename}:{code.co_firstlineno}")
    templates = (_centralised,) if cls.centralised else (_agent, features)
    lines.append("# the template, with them in place of COEFFICIENTS, TERMS_OF, FEATURE, TRANSMIT and STEPS_OF:")
    lines += [inspect.getsource(t) for t in templates]
    lines.append("# the accessors spelled out for its fields, messages, products and directions:")
    lines.append(compiled.generated)
    return "\n".join(lines)


def writes_one_definition(cls) -> bool:
    """Whether algorithm class ``cls`` writes its arithmetic in the one definition (`dgtd.algorithms.base`) that the
    compiled driver runs, rather than ``update`` alone."""
    return cls.feature is not base.StepSizes.feature and cls.update is base.StepSizes.update


_USERS: dict[type, CompiledStep] = {}
_REGISTERED: dict[str, CompiledStep] = {}


def registered_step(cls) -> CompiledStep:
    """The compiled step of a registered algorithm class (`dgtd.algorithms.ALGORITHMS`), made once per process."""
    if cls.name not in _REGISTERED:
        _REGISTERED[cls.name] = compiled_step(cls(), cls.name.replace("-", "_"))
    return _REGISTERED[cls.name]


def step_of(algorithm) -> CompiledStep | None:
    """The compiled step of ``algorithm`` (an instance): the registered algorithm's, or one made from a user's class
    (`user_step`); None where it writes ``update`` alone."""
    cls = type(algorithm)
    if ALGORITHMS.get(cls.name) is cls:
        return registered_step(cls)
    return user_step(algorithm)


def user_step(algorithm) -> CompiledStep | None:
    """The compiled step of a user's algorithm, made once per process and class from its one definition and not cached
    on disk (numba cannot tell when the user's file changes); None for one that writes ``update`` alone."""
    cls = type(algorithm)
    if not writes_one_definition(cls):
        return None
    if cls not in _USERS:
        key = "user_" + "".join(c if c.isalnum() else "_" for c in f"{cls.__qualname__}_{len(_USERS)}")
        _USERS[cls] = compiled_step(algorithm, key, cache=False)
    return _USERS[cls]


def _in(space: dict, fn, name: str):
    """Template ``fn`` compiled (to be inlined) with the globals ``space``."""
    return njit(inline="always")(types.FunctionType(fn.__code__, space, name, fn.__defaults__))


def _compiled(fn):
    """``fn`` compiled to be inlined, with the plain functions it calls compiled alike and `clip` in place of
    `dgtd.algorithms.base.clip` (NumPy's)."""
    fn = getattr(fn, "__func__", fn)
    names = {}
    for name in fn.__code__.co_names:
        value = fn.__globals__.get(name)
        if value is base.clip:
            names[name] = clip
        elif isinstance(value, types.FunctionType):
            names[name] = _compiled(value)
    space = dict(fn.__globals__, **names)
    clone = types.FunctionType(fn.__code__, space, fn.__name__, fn.__defaults__, fn.__closure__)
    return njit(inline="always")(clone)


def _agent(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """Agent i of seed b at step k: its aggregates, products and coefficients, then feature by feature its directions
    and its new state (`dgtd.algorithms.base`); the running sum of w kept."""
    sent, L, at = inbox.sent, inbox.sums, inbox.at
    s, sn, r, ratio, gamma = transition(x, agent)
    for m in range(M):
        if METROPOLIS:
            metropolis(inbox, m, b, i)  # (L_W(k) x)_i
        else:
            laplacian(inbox, m, b, i)  # (L(k) x)_i
    c = COEFFICIENTS(p, PRODUCTS(feat, s, sn, own, sent, b, i, q), r, ratio, gamma)
    steps = STEPS_OF(p, alpha)
    if feat.sparse:  # dense rows of phi(s) and phi(s'), read as the dense features are
        phi_times(feat, s, 1.0, work, (PHI, at), q)
        phi_times(feat, sn, 1.0, work, (PHI_NEXT, at), q)
        features(p, own, sums, L, sent, out, work[PHI, at], work[PHI_NEXT, at], c, gamma, steps, b, i, at, q)
    else:
        features(p, own, sums, L, sent, out, feat.Phi[s], feat.Phi[sn], c, gamma, steps, b, i, at, q)


def features(p, own, sums, L, sent, out, phi_row, phi_next_row, c, gamma, steps, b, i, at, q):
    """Agent i's features, one by one: its directions and its new state (one loop, which LLVM vectorises)."""
    w_in, w_row = W_AT
    for f in range(q):
        sums[b, i, f] += sent[w_row, b, i, f] if w_in else own[w_row, b, i, f]
        d = TERMS_OF(p, phi_row[f], phi_next_row[f], c, gamma)
        new = FEATURE(p, LOAD_STATE(own, sent, b, i, f), LOAD_HEARD(L, at, f), d, steps)
        STORE(own, out, b, i, f, new, TRANSMIT(new))


def _centralised(p, own, sums, inbox, out, work, x, feat, b, i, agent, alpha, q):
    """The one learner of seed b at step k: the directions of the N observed transitions summed, then feature by
    feature their mean through its ``feature`` (`dgtd.algorithms.base`); the running sum of w kept."""
    at, N = inbox.at, x.r.shape[1]
    w_row = W_AT[1]
    for f in range(q):
        sums[b, 0, f] += own[w_row, b, 0, f]
        for k in range(N_TERMS):
            work[TERMS + k, at, f] = 0.0
    for o in range(N):
        s, sn, r, ratio, gamma = transition(x, o)
        c = COEFFICIENTS(p, PRODUCTS(feat, s, sn, own, own, b, 0, q), r, ratio, gamma)
        if feat.sparse:  # the directions vanish where phi_f(s) = phi_f(s') = 0
            for k in range(feat.ptr[s], feat.ptr[s + 1]):
                f = feat.idx[k]
                ADD_TERMS(work, at, f, TERMS_OF(p, feat.val[k], phi_value(feat, sn, f), c, gamma))
            for k in range(feat.ptr[sn], feat.ptr[sn + 1]):
                f = feat.idx[k]
                if phi_value(feat, s, f) == 0.0:  # not done above
                    ADD_TERMS(work, at, f, TERMS_OF(p, 0.0, feat.val[k], c, gamma))
        else:
            for f in range(q):
                ADD_TERMS(work, at, f, TERMS_OF(p, feat.Phi[s, f], feat.Phi[sn, f], c, gamma))
    steps = STEPS_OF(p, alpha)
    for f in range(q):
        for k in range(N_TERMS):
            work[TERMS + k, at, f] = work[TERMS + k, at, f] / N  # the mean over the N transitions
        new = FEATURE(p, LOAD_STATE(own, own, b, 0, f), (), LOAD_TERMS(work, at, f), steps)
        STORE(own, out, b, 0, f, new, ())


class Samples(NamedTuple):
    """The samples of one step of one seed: observations s, a, s' (row ``row`` of (rows, n) arrays: n = N, or 1 on a
    shared trajectory), every agent's reward r (rows, N), the ratio table (S, A), the continuing flags c (S,) and
    gamma."""

    s: np.ndarray
    a: np.ndarray
    s_next: np.ndarray
    r: np.ndarray
    row: int
    ratio: np.ndarray
    continuing: np.ndarray
    gamma: float


@njit(cache=True, inline="always")
def transition(x, agent):
    """(s, s', r, ratio, gamma(s, s')) of ``agent``'s transition (its own observation, or the shared one):
    gamma(s, s') = gamma c(s) c(s') is 0 into and out of an episodic task's terminal states (`Block.sample`)."""
    o = agent if x.s.shape[1] == x.r.shape[1] else 0
    s, sn = x.s[x.row, o], x.s_next[x.row, o]
    return s, sn, x.r[x.row, agent], x.ratio[s, x.a[x.row, o]], x.gamma * x.continuing[s] * x.continuing[sn]


class Features(NamedTuple):
    """The features the observations index: dense rows ``Phi`` (S, q), or, where ``sparse``, only the CSR rows
    (``ptr``, ``idx``, ``val``) of their nonzero entries (``Phi`` is then a row of zeros)."""

    Phi: np.ndarray
    sparse: bool
    ptr: np.ndarray
    idx: np.ndarray
    val: np.ndarray


@njit(cache=True, inline="always")
def phi_dot(feat, s, X, at, q):
    """phi(s)^T X[*at] (the row ``at``, a tuple of indices), in a fixed order (dense: `dot`; sparse: the nonzero
    features in increasing order)."""
    if feat.sparse:
        acc = 0.0
        for p in range(feat.ptr[s], feat.ptr[s + 1]):
            acc += feat.val[p] * X[at + (feat.idx[p],)]
        return acc
    return dot(feat.Phi, s, X, at, q)  # type: ignore[call-arg]


@njit(cache=True, inline="always")
def phi_axpy(feat, s, c, X, at, q):
    """X[*at] += c phi(s)."""
    if feat.sparse:
        for p in range(feat.ptr[s], feat.ptr[s + 1]):
            X[at + (feat.idx[p],)] += c * feat.val[p]
    else:
        for f in range(q):
            X[at + (f,)] += c * feat.Phi[s, f]


@njit(cache=True, inline="always")
def phi_times(feat, s, c, X, at, q):
    """X[*at] = c phi(s): a row of a step's work, which its loops over the features then read (a feature's phi_f(s)
    looked up inside such a loop would keep it from being vectorised)."""
    if feat.sparse:
        for f in range(q):
            X[at + (f,)] = 0.0
        for p in range(feat.ptr[s], feat.ptr[s + 1]):
            X[at + (feat.idx[p],)] = c * feat.val[p]
    else:
        for f in range(q):
            X[at + (f,)] = c * feat.Phi[s, f]


@njit(cache=True, inline="always")
def phi_value(feat, s, f):
    """phi_f(s) (where sparse, a search of the row's few nonzero features)."""
    if not feat.sparse:
        return feat.Phi[s, f]
    for p in range(feat.ptr[s], feat.ptr[s + 1]):
        if feat.idx[p] == f:
            return feat.val[p]
    return 0.0


@njit(cache=True, inline="always")
def clip(x, bound):
    """Projection onto [-bound, bound]; NaN stays NaN. Testing the inner result rather than x twice lets LLVM emit one
    min and one max instruction (a compare and a blend per test otherwise)."""
    inner = bound if x > bound else x
    return -bound if inner < -bound else inner
