"""The code's shape, checked: no import cycles (imports inside functions included), no function longer than a
screen or more tangled than a reader follows, and the run loop and the command line name no MPI."""

from __future__ import annotations

import ast
from pathlib import Path

SRC = Path(__file__).resolve().parents[1] / "src"
MAX_LINES, MAX_COMPLEXITY = 80, 12


def modules() -> dict[str, Path]:
    """Every module of dgtd by its dotted name."""
    found = {}
    for path in (SRC / "dgtd").rglob("*.py"):
        parts = list(path.relative_to(SRC).with_suffix("").parts)
        found[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return found


def imported(name: str, path: Path, known: dict) -> set[str]:
    """The dgtd modules ``name`` imports anywhere in its file (a name imported from a package counts as its module
    where it is one)."""
    out = set()
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([base] if base else []))
            out |= {f"{base}.{a.name}" if f"{base}.{a.name}" in known else base for a in node.names}
    return {m for m in out if m in known and m != name}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while (w := stack.pop()) != v:
                component.append(w)
            if component:
                found.append(sorted([v, *component]))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def test_no_import_cycles_even_through_imports_inside_functions():
    known = modules()
    graph = {name: imported(name, path, known) for name, path in known.items()}
    assert cycles(graph) == []


def test_the_cycle_finder_finds_a_cycle():
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]


def complexity(fn: ast.AST) -> int:
    """McCabe's cyclomatic complexity as ruff's C901 counts it (equal on every function of src/ when written): 1, and
    1 for each if, loop and match case, 1 for each except clause and a try's else, a nested function's own."""
    n = 1
    for child in ast.iter_child_nodes(fn):
        n += _branches(child)
    return n


def _branches(node: ast.AST) -> int:
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
        return complexity(node)
    if isinstance(node, ast.Lambda | ast.ClassDef):
        return 0
    n = 0
    if isinstance(node, ast.If | ast.For | ast.AsyncFor | ast.While | ast.match_case):
        n = 1
    elif isinstance(node, ast.Try):
        n = len(node.handlers) + (1 if node.orelse else 0)
    return n + sum(_branches(child) for child in ast.iter_child_nodes(node))


def body_lines(fn) -> int:
    """A function's lines, its docstring aside."""
    body = fn.body
    documented = len(body) > 1 and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
    return fn.end_lineno - (body[1] if documented else body[0]).lineno + 1


def oversized() -> set[str]:
    out = set()
    for path in (SRC / "dgtd").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                if body_lines(node) > MAX_LINES or complexity(node) > MAX_COMPLEXITY:
                    out.add(f"{path.relative_to(SRC).as_posix()}:{node.name}")
    return out


def test_no_function_is_longer_than_a_screen_or_too_tangled():
    assert oversized() == set(), "split these: at most 80 lines (the docstring aside) and complexity 12"


def test_the_bounds_see_a_long_tangled_function(tmp_path):
    body = "".join(f"    if x == {k}:\n        x += 1\n" for k in range(13))
    tree = ast.parse(f"def f(x):\n{body}    return x\n")
    fn = tree.body[0]
    assert complexity(fn) == 14 and body_lines(fn) == 27


MPI_NAMES = {"mpi", "mpi4py", "MPI", "comm", "world", "COMM_WORLD", "rank", "Get_rank", "bcast", "Ranks"}


def names_used(path: Path) -> set[str]:
    """Every module imported and every name and attribute read in a file."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import | ast.ImportFrom):
            out |= {part for a in node.names for part in a.name.split(".")}
            out |= set((getattr(node, "module", None) or "").split("."))
        elif isinstance(node, ast.Name):
            out.add(node.id)
        elif isinstance(node, ast.Attribute):
            out.add(node.attr)
        elif isinstance(node, ast.arg):
            out.add(node.arg)
    return out


def test_the_run_loop_and_the_command_line_name_no_mpi():
    files = [SRC / "dgtd/run/loop.py", *sorted((SRC / "dgtd/cli").glob("*.py"))]
    named = {path.name: names_used(path) & MPI_NAMES for path in files}
    assert {name: found for name, found in named.items() if found} == {}


def test_the_mpi_check_sees_a_communicator(tmp_path):
    f = tmp_path / "x.py"
    f.write_text("from dgtd.backends import mpi\ndef f(comm):\n    return mpi.world().bcast(None)\n")
    assert names_used(f) & MPI_NAMES == {"mpi", "comm", "world", "bcast"}


def learning_loops(paths) -> list[str]:
    """The functions of ``paths`` that loop over a learning run's steps (a ``for k in range(...)``)."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef):
                loops = [n for n in ast.walk(node) if isinstance(n, ast.For) and isinstance(n.target, ast.Name)]
                if any(n.target.id == "k" and ast.unparse(n.iter).startswith("range(") for n in loops):
                    found.append(f"{path.name}:{node.name}")
    return found


def test_models_and_simulators_are_learned_in_one_loop():
    """One learning loop (`dgtd.run.learn.learn`) runs a model's steps and a simulator's, through the protocol of
    `dgtd.sources.team_env`; the learners' arithmetic lives in `dgtd.algorithms` (a second loop once carried its own
    copy of the actor, the TD error and the team-reward regression)."""
    assert learning_loops(sorted((SRC / "dgtd" / "run").glob("learn*.py"))) == ["learn.py:learn"]


def test_the_loop_check_sees_a_second_loop(tmp_path):
    (tmp_path / "learn_more.py").write_text("def again(T):\n    for k in range(T):\n        pass\n")
    assert learning_loops([tmp_path / "learn_more.py"]) == ["learn_more.py:again"]


WRITERS = {"atomic_write", "savez", "savez_compressed", "write_bytes"}


def checkpoint_writers(paths) -> list[str]:
    """The calls in ``paths`` that write a file whose path names a checkpoint (outside `dgtd.run.checkpoint`)."""
    found = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call):
                name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
                target = ast.unparse(node.func.value) if isinstance(node.func, ast.Attribute) else ""
                said = (ast.unparse(node.args[0]) if node.args else "") + " " + target  # (the path written)
                if name in WRITERS and "checkpoint" in said.lower():
                    found.append(f"{path.name}:{node.lineno}")
    return found


def test_one_checkpoint_writer():
    """Every checkpoint, a run's and a learning run's, is written by `dgtd.run.checkpoint.save_checkpoint` in one
    format (a learning run once wrote its own flat .npz beside it)."""
    paths = [p for p in sorted((SRC / "dgtd").rglob("*.py")) if p != SRC / "dgtd" / "run" / "checkpoint.py"]
    assert checkpoint_writers(paths) == []


def test_the_writer_check_sees_a_second_writer(tmp_path):
    (tmp_path / "keep.py").write_text("def keep(out, b):\n    atomic_write(out / CHECKPOINT, b)\n")
    assert checkpoint_writers([tmp_path / "keep.py"]) == ["keep.py:2"]


def rank_layouts(path) -> dict:
    """{class: whether it builds the run's `Partition`} of the classes in ``path`` that say which agents a rank
    holds (an attribute ``local`` or ``agents`` set in ``__init__``)."""
    found = {}
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ClassDef):
            init = next((f for f in node.body if isinstance(f, ast.FunctionDef) and f.name == "__init__"), None)
            if init is None:
                continue
            text = ast.unparse(init)
            if "self.local =" in text or "self.agents" in text:
                found[node.name] = "Partition.of(" in text or "partition(ctx)" in text
    return found


def test_one_rank_layout():
    """Agents are spread over ranks one way, the run's `dgtd.backends.mpi.Partition` (contiguous blocks, ghosts by
    a halo exchange): the run's layout and the learners' both build it, and no module splits the agents another way
    (the learners once split them by np.array_split and gathered every agent's messages on every rank)."""
    layouts = rank_layouts(SRC / "dgtd" / "backends" / "mpi.py")
    assert set(layouts) == {"Ranks", "LearnerRanks"} and all(layouts.values()), layouts
    assert [p.name for p in (SRC / "dgtd").rglob("*.py") if "array_split(" in p.read_text()] == []


def test_the_layout_check_sees_a_second_layout(tmp_path):
    (tmp_path / "mine.py").write_text(
        "class Mine:\n    def __init__(self, n, R, r):\n        self.local = np.array_split(np.arange(n), R)[r]\n"
    )
    assert rank_layouts(tmp_path / "mine.py") == {"Mine": False}
