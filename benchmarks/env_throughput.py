"""Env steps and agent-steps per second of runs on simulators: the environment alone, dgtd's sampling, a whole run.

    python benchmarks/env_throughput.py                 # every env, 3 interleaved repeats, writes the docs too
    python benchmarks/env_throughput.py --repeats 1 --no-docs

For each environment three numbers, in env steps per second (one step of one copy: all N agents act once, so
agent-steps per second are N times as many):

- **env alone**: ``env.step`` with random actions in a plain Python loop, resets included: the ceiling;
- **sampling**: `dgtd.sources.env.EnvSource` with the scenario's policy and features, 4 copies (seeds), blocks of
  1,024 steps: what dgtd adds is the policy calls, the state and reward dicts, and the features in one batch;
- **run**: a whole DGTD run of 20,000 steps x 4 seeds on that source (`dgtd.run.loop.run`), the kernels warm.

The repeats are interleaved (every env once, then again), as this machine is shared; the table gives the range.
Writes env_throughput.md and .json under --out and, unless --no-docs, the table into docs/benchmarks.md between
its markers.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np

from dgtd.cli.bench import machine
from dgtd.config import ProblemConfig, RunConfig, resolve, scenario_of
from dgtd.run.loop import RunSettings, run

ROOT = Path(__file__).resolve().parents[1]
BEGIN, END = "<!-- env-throughput: begin -->", "<!-- env-throughput: end -->"
CHAIN = f"{ROOT / 'tests' / 'envs' / 'chain.py'}:make_chain"
ENVS = {  # name -> the run's config
    "chain (PettingZoo, 3 agents, one-hot)": RunConfig(ProblemConfig(env={"make": CHAIN, "features": "one-hot"})),
    "CartPole-v1 split among 3 (Gymnasium, fourier:2)": RunConfig(
        ProblemConfig(env={"make": "gymnasium:CartPole-v1", "agents": 3, "features": "fourier:2"})
    ),
    "mpe-spread, 3 agents (MPE2)": RunConfig(ProblemConfig(scenario="mpe-spread", params={"agents": 3})),
    "mpe-spread, 6 agents (MPE2)": RunConfig(ProblemConfig(scenario="mpe-spread", params={"agents": 6})),
}
SEEDS, STEPS, BLOCK = 4, 20_000, 1024


def env_alone(source, steps: int) -> float:
    """Env steps per second of one copy's ``env.step`` with random actions, resets included."""
    env = source.make_env()
    rng = np.random.default_rng(0)
    env.reset(seed=0)
    spaces = {a: env.action_space(a) for a in env.possible_agents}
    t0 = time.perf_counter()
    for _ in range(steps):
        actions = {a: int(rng.integers(spaces[a].n)) for a in env.agents}
        _, _, terms, truncs, _ = env.step(actions)
        if not env.agents or any(terms.values()) or any(truncs.values()):
            env.reset(seed=int(rng.integers(2**31)))
    return steps / (time.perf_counter() - t0)


def sampling(make_source, steps: int) -> float:
    source = make_source(0, range(SEEDS))
    source.start()
    t0 = time.perf_counter()
    for _ in range(steps // BLOCK):
        source.next_block(BLOCK)
    return (steps // BLOCK) * BLOCK * SEEDS / (time.perf_counter() - t0)


def whole_run(problem, network, algorithm, sampling_mode, make_source, steps: int) -> float:
    settings = RunSettings(iterations=steps, seeds=SEEDS, checkpoints=10, block_size=BLOCK)
    t0 = time.perf_counter()
    run(problem, network, algorithm, sampling_mode, settings, source=make_source(0, range(SEEDS)))
    return steps * SEEDS / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    ap.add_argument("--no-docs", action="store_true")
    args = ap.parse_args()
    prepared = {}
    for name, spec in ENVS.items():
        problem, network, algorithm, samp, settings, resolved, channel = resolve(spec)
        sc = scenario_of(resolved)
        prepared[name] = (problem, network, algorithm, samp, sc.source)
        whole_run(problem, network, algorithm, samp, sc.source, BLOCK)  # the kernels compiled and loaded
    rates = {name: {"env alone": [], "sampling": [], "run": []} for name in ENVS}
    for r in range(args.repeats):
        for name, (problem, network, algorithm, samp, make_source) in prepared.items():
            rates[name]["env alone"].append(env_alone(make_source(0, [0]), STEPS // 4))
            rates[name]["sampling"].append(sampling(make_source, STEPS))
            rates[name]["run"].append(whole_run(problem, network, algorithm, samp, make_source, STEPS))
            print(
                f"repeat {r + 1}: {name}: " + ", ".join(f"{k} {v[-1]:,.0f}/s" for k, v in rates[name].items()),
                flush=True,
            )
    table = [
        "| environment | agents | env alone (env steps/s) | sampling (env steps/s) | run (env steps/s) | run "
        "(agent-steps/s) | dgtd's share of a run's time, per repeat |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, (problem, *_rest) in prepared.items():
        n = problem.n_agents
        env, samp, whole = (np.array(rates[name][k]) for k in ("env alone", "sampling", "run"))
        span = lambda x, f=1: f"{x.min() * f:,.0f} - {x.max() * f:,.0f}"  # noqa: E731
        share = 1 - whole / env  # paired within a repeat, as the machine's load changes between repeats
        table.append(
            f"| {name} | {n} | {span(env)} | {span(samp)} | {span(whole)} | {span(whole, n)} | "
            f"{share.min():.0%} - {share.max():.0%} |"
        )
    text = "\n".join(table) + f"\n\n{args.repeats} interleaved repeats, {SEEDS} copies, {machine()}."
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "env_throughput.md").write_text(text + "\n")
    (args.out / "env_throughput.json").write_text(json.dumps(rates, indent=1))
    print(text)
    if not args.no_docs:
        docs = ROOT / "docs" / "benchmarks.md"
        old = docs.read_text()
        if BEGIN not in old:
            raise SystemExit(f"{docs} has no {BEGIN} marker")
        docs.write_text(
            re.sub(re.escape(BEGIN) + ".*?" + re.escape(END), lambda _: f"{BEGIN}\n{text}\n{END}", old, flags=re.S)
        )


if __name__ == "__main__":
    main()
