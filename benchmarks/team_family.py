"""How often learners reach the team's best policy, on a family of random team MDPs, and why they do not.

The family (made here, the same on every machine): MDP m draws from numpy's default_rng(1000 + m) its agents N in
{2, 3, 4} and states S in {3, ..., 6}, binary actions, every row P(s, a, .) uniform on the simplex (Dirichlet(1)) over
the 2^N joint actions, every agent's reward R_i(s, a) uniform in [0, 1], tabular features, uniform starting policies.
Each is written as a problem file and run as `dgtd learn --problem FILE --seeds 4 --actor A` runs it, default settings
(the long-run average objective, 20 000 steps, DGTD critics on a ring of the agents).

For every run: the gap of its last policies' long-run average J to J*, (J* - J) / J*; and where it is more than 2 %,
why: its policies rounded to their likeliest actions either reach J* within 2 % (still moving: "slow"), or form a
person-by-person optimum, a joint policy no single agent can improve on by changing its own policy (each agent's exact
best response to the others', by relative value iteration on the MDP their policies leave it:
`dgtd.problems.team.relative_value_iteration`), or neither ("other"). ``--objective discounted --actor-warmup 0``
gives the learners of before the average objective (critics discounted at the files' gamma 1/2, actors moving from
the first step), their J still the long-run average. Softmax actors that ascend J each along their own gradient
can stop at any such point: random team MDPs have many (a 4-agent, 3-state one of this family has 46).
Usage: python benchmarks/team_family.py [--mdps 50] [--seeds 4] [--objective O] [--actor-warmup K] [--out DIR]"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from dgtd.learning import resolve_learning
from dgtd.problems import team
from dgtd.run.learn import learn, local_policies

LEARNERS = ("networked", "centralised", "independent")
WITHIN = 0.02  # "reached J*": within 2 %


def family_member(m: int, folder: Path) -> Path:
    """Team MDP m of the family (the module's docstring), written as a problem file in ``folder``."""
    rng = np.random.default_rng(1000 + m)
    N, S = int(rng.integers(2, 5)), int(rng.integers(3, 7))
    P = rng.dirichlet(np.ones(S), size=(S, 2**N))
    R = rng.uniform(0.0, 1.0, (N, S, 2**N))
    path = folder / f"random-{m}.npz"
    policies = {f"policy_{i}": np.full((S, 2), 0.5) for i in range(N)}
    np.savez(path, P=P, R=R, Phi=np.eye(S), gamma=0.5, **policies)
    return path


def best_response(mdp: team.TeamMDP, policies: list, i: int) -> float:
    """The long-run average agent i reaches by its best policy while the others keep ``policies``."""
    S, n = mdp.n_states, mdp.actions[i]
    P_i, r_i = np.zeros((S, n, S)), np.zeros((S, n))
    for a in range(n):  # agent i's action a in every state, the others' policies as they are
        joint = team.joint_policy([p if j != i else np.eye(n)[np.full(S, a)] for j, p in enumerate(policies)])
        P_i[:, a], r_i[:, a] = np.einsum("sa,sat->st", joint, mdp.P), (joint * mdp.R.mean(axis=0)).sum(axis=1)

    def sweep(h):
        Q = r_i + P_i @ h
        return Q.max(axis=1), Q.argmax(axis=1)

    return team.relative_value_iteration(mdp.n_states, sweep)[0]


def person_by_person(mdp: team.TeamMDP, policies: list) -> tuple[bool, float]:
    """(whether the policies rounded to their likeliest actions are a person-by-person optimum, their J)."""
    rounded = [np.eye(p.shape[1])[p.argmax(axis=1)] for p in policies]
    J = team.average_return(mdp, rounded)
    return all(best_response(mdp, rounded, i) <= J + 1e-9 for i in range(mdp.n_agents)), J


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--mdps", type=int, default=50)
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument("--objective", default="average")
    parser.add_argument("--actor-warmup", type=int, default=None)
    parser.add_argument("--out", default=None, help="where the problem files go (default: a temporary folder)")
    args = parser.parse_args()
    folder = Path(args.out or tempfile.mkdtemp(prefix="team-family-"))
    folder.mkdir(parents=True, exist_ok=True)
    print(f"{'learners':<13}{'runs':>6}{'within 2%':>11}{'median gap':>12}{'worst gap':>11}{'slow':>6}"
          f"{'at a pbp optimum':>18}{'other':>7}{'seconds':>9}")  # fmt: skip
    for learners in LEARNERS:
        gaps, why, started = [], {"slow": 0, "optimum": 0, "other": 0}, time.perf_counter()
        for m in range(args.mdps):
            options = {"objective": args.objective, "actor_warmup": args.actor_warmup}
            job = resolve_learning(None, {"problem_file": str(family_member(m, folder)), "seeds": args.seeds,
                                          "actor": learners, "checkpoints": 1, **options})  # fmt: skip
            result = learn(job.mdp, job.network, job.critic, job.actor, job.settings, job.channel)
            J_star = job.mdp.best_return()[0]
            for pi in result.policies:
                policies = local_policies(job.mdp, pi)
                gaps.append((J_star - team.average_return(job.mdp, policies)) / J_star)
                if gaps[-1] > WITHIN:
                    optimum, J_rounded = person_by_person(job.mdp, policies)
                    kind = "slow" if J_rounded >= (1 - WITHIN) * J_star else "optimum" if optimum else "other"
                    why[kind] += 1
        g = np.array(gaps)
        print(
            f"{learners:<13}{len(g):>6}{np.mean(g <= WITHIN):>11.0%}{np.median(g):>12.4f}{g.max():>11.3f}"
            f"{why['slow']:>6}{why['optimum']:>18}{why['other']:>7}{time.perf_counter() - started:>9.0f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
