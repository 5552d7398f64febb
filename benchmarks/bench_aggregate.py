"""Cost of the probability of improvement's bootstrap in ``aggregate.py``.

``recipes/results/aggregate.py`` gives, for every ordered pair of settings of a
task, P(X > Y) with a 95% stratified-bootstrap CI (rliable's
``get_interval_estimates``, ``--reps`` replications, 2,000 by default): with 11
settings that is 110 estimates, each calling the metric once per replication.
This times one such estimate, on two settings of ``--seeds`` seeds each, with
rliable's ``metrics.probability_of_improvement`` (a SciPy Mann-Whitney test per
call) and with ``aggregate.probability_of_improvement`` (the same count in
NumPy), interleaved over ``--rounds`` rounds (the order alternates), and prints
each round's times (after an untimed warm-up), the median ratio and whether the
two intervals are equal (the scores are distinct: ties are tested in
``tests/test_aggregate.py``).

Run: ``python benchmarks/bench_aggregate.py`` (about 15 s).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))


def main(argv=None) -> int:
    from rliable import metrics

    from results.aggregate import (
        _bootstrap_seed,
        _interval_estimate,
        probability_of_improvement,
    )

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--reps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=4)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    x, y = rng.random((args.seeds, 1)), rng.random((args.seeds, 1))
    seed = _bootstrap_seed(0, "bench")
    metrics_by_name = {
        "rliable": metrics.probability_of_improvement,
        "numpy": probability_of_improvement,
    }
    for metric in metrics_by_name.values():  # warm-up, untimed (first imports)
        _interval_estimate([x, y], metric, 10, seed)
    times = {name: [] for name in metrics_by_name}
    intervals = {}
    for round_ in range(args.rounds):
        names = list(metrics_by_name)[:: 1 if round_ % 2 == 0 else -1]
        for name in names:
            start = time.perf_counter()
            _, intervals[name] = _interval_estimate(
                [x, y], metrics_by_name[name], args.reps, seed
            )
            times[name].append(time.perf_counter() - start)
        print(
            f"round {round_}: rliable {times['rliable'][-1]:.3f} s, "
            f"numpy {times['numpy'][-1]:.3f} s"
        )
    ratios = np.array(times["rliable"]) / np.array(times["numpy"])
    same = np.array_equal(intervals["rliable"], intervals["numpy"])
    print(
        f"one estimate, {args.seeds} vs {args.seeds} seeds, {args.reps} reps: "
        f"numpy {np.median(ratios):.1f}x faster than rliable's metric (median of "
        f"{args.rounds} rounds), same interval: {same} "
        f"(load average {os.getloadavg()[0]:.2f})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
