#!/usr/bin/python3
"""Cross-check of the core's offline EM (src/core/cell/offline_em.cpp) against pomegranate.

Usage:
    compare_pomegranate.py OFFLINE_EM_CLI [--cells N] [--iterations N] [--seed S]
    compare_pomegranate.py OFFLINE_EM_CLI --benchmark [--bench-cells N] [--bench-steps N]

OFFLINE_EM_CLI is the test tool test/tools/offline_em_cli.cpp (its input/output format is
described at the top of that file). Runs with /usr/bin/python3 and Debian's
python3-pomegranate (0.14.x) and numpy.

What is compared. Random short cell sequences (fixed seed) are given to the CLI, which runs
runOfflineEm with maximum likelihood (p_min = 0, p_max = 1, no prior, tolerance 0) for exactly
N M-steps. For each cell, a pomegranate HiddenMarkovModel with two states is fitted with
Baum-Welch for exactly N M-steps, and the learned transition probabilities and the final
log-likelihood must agree to 1e-6 (absolute).

How pomegranate is made to compute the same model:
  * One pomegranate symbol per step: "n" for a step without observation, "h{h}m{m}" for an
    observed step with h hits and m misses. The chain starts the step before the first
    observation with p(occ) = initial_p_occ (the project's convention), so the sequence is
    ["n"] + one symbol per step from t_1 to t_n.
  * Emissions are FROZEN DiscreteDistributions: P(h{h}m{m} | s) = kappa * p(hit|s)^h
    (1 - p(hit|s))^m, P(n | s) = kappa for both states, and a never-observed "slack" symbol
    takes the rest. Constant factors do not change posteriors, so EM is the same; the
    log-likelihoods differ by len(sequence) * log(kappa).
  * Start probabilities are pinned with per-edge pseudocounts of 1e12 * q (use_pseudocount);
    the four real edges get a negligible pseudocount (1e-300), NOT 0: pomegranate 0.14's
    add_transition does `pseudocount = pseudocount or probability`, so 0 silently becomes the
    edge's initial probability.
  * Iterations: pomegranate's fit() loop does an M-step (from_summaries) at the top of every
    pass, then breaks once iteration >= max_iterations + 1, so min_iterations =
    max_iterations = N with a tiny stop_threshold does N + 1 M-steps (or N, if the last
    improvement happens to be <= stop_threshold). Exactly N M-steps: stop_threshold = +inf
    with min_iterations = N (the loop then ends on its while condition after the E-step
    on the N-th parameters). max_iterations = N - 1 with stop_threshold = -inf also does N
    M-steps but crashes for N = 1 (UnboundLocalError: 'logs', pomegranate 0.14.8 needs at
    least two E-steps). The script checks the meaning of N on both sides: the CLI's N - 1
    and N + 1 runs must NOT match pomegranate's N.

A plain numpy Baum-Welch (step by step, no closed forms) runs on a few cells as a third
opinion, so that a mismatch can be blamed on the right side.

Exit status: 0 when everything matches, 1 on a mismatch or when pomegranate is missing,
2 when the CLI fails.
"""

import argparse
import math
import subprocess
import sys
import time

try:
    import numpy as np
except ImportError as error:  # pragma: no cover - environment problem
    print(f"compare_pomegranate: FAIL: numpy is not importable ({error}); install python3-numpy "
          "(scripts/setup.sh installs it)")
    sys.exit(1)
try:
    import pomegranate as pg
except ImportError as error:
    print(f"compare_pomegranate: FAIL: pomegranate is not importable ({error}); install "
          "python3-pomegranate (sudo apt-get install python3-pomegranate; scripts/setup.sh "
          "installs it). This cross-check does not pass without it.")
    sys.exit(1)

TOLERANCE = 1e-6
START_PSEUDOCOUNT = 1e12
EDGE_PSEUDOCOUNT = 1e-300  # not 0: pomegranate replaces a falsy pseudocount by the probability
OCC, FREE = 0, 1


class Dataset:
    """One CLI run's worth of cells, with the shared sensor and EM start."""

    def __init__(self, name, p_hit_occ, p_hit_free, initial_p_occ, p_of0, p_fo0, cells):
        self.name = name
        self.p_hit = (p_hit_occ, p_hit_free)
        self.initial_p_occ = initial_p_occ
        self.p_of0 = p_of0
        self.p_fo0 = p_fo0
        self.cells = cells  # list of lists of (step, hits, misses), steps strictly increasing

    def observed_steps(self):
        return sum(len(cell) for cell in self.cells)


def simulate_cell(rng, p_hit, initial_p_occ, n_obs, gap_max, counts_max, first_step):
    """A cell with random true transitions, observed n_obs times with gaps 1..gap_max."""
    p_of, p_fo = rng.uniform(0.01, 0.6, size=2)
    state = OCC if rng.random() < initial_p_occ else FREE
    step = first_step - 1
    cell = []
    for _ in range(n_obs):
        gap = int(rng.integers(1, gap_max + 1))
        for _ in range(gap):
            if state == OCC:
                state = FREE if rng.random() < p_fo else OCC
            else:
                state = OCC if rng.random() < p_of else FREE
        step += gap
        while True:  # beams of the step; 0..counts_max hits and misses, not both 0
            beams = int(rng.integers(1, 2 * counts_max + 1))
            hits = int(rng.binomial(beams, p_hit[state]))
            misses = beams - hits
            if hits <= counts_max and misses <= counts_max:
                break
        cell.append((step, hits, misses))
    return cell


def make_datasets(seed, cells):
    rng = np.random.default_rng(seed)
    datasets = []
    # The brief's data: short sequences, 5-40 observed steps, gaps 1-6, counts 0..2.
    for name, p_hit, q0, start in (("main", (0.7, 0.2), 0.5, (0.1, 0.2)),
                                   ("sharp-sensor", (0.9, 0.05), 0.3, (0.3, 0.05))):
        data = [simulate_cell(rng, p_hit, q0, int(rng.integers(5, 41)), 6, 2,
                              int(rng.integers(-50, 1000))) for _ in range(cells)]
        datasets.append(Dataset(name, *p_hit, q0, *start, data))
    # Edge cases: 1-3 observations, long gaps, larger counts, a weak sensor, negative steps.
    data = []
    for i in range(max(cells // 5, 10)):
        n_obs = [1, 2, 3][i % 3] if i < 15 else int(rng.integers(4, 30))
        data.append(simulate_cell(rng, (0.55, 0.45), 0.8, n_obs, 60 if i % 2 else 6, 5,
                                  int(rng.integers(-200, 200))))
    datasets.append(Dataset("edge", 0.55, 0.45, 0.8, 0.45, 0.02, data))
    return datasets


# ----------------------------------------------------------------------------- the CLI side

def cli_input(dataset, iterations, tolerance, threads):
    lines = [f"{dataset.p_hit[0]!r} {dataset.p_hit[1]!r} {dataset.initial_p_occ!r} "
             f"{dataset.p_of0!r} {dataset.p_fo0!r} {iterations} {tolerance!r} {threads}"]
    for cell in dataset.cells:
        lines.append(" ".join([str(len(cell))] + [f"{s} {h} {m}" for s, h, m in cell]))
    return "\n".join(lines) + "\n"


def run_cli(cli, dataset, iterations, threads=1, extra=()):
    """Returns (rows, objective, seconds); rows = per cell (p_of, p_fo, iterations,
    final_p_occ, log_likelihood)."""
    text = cli_input(dataset, iterations, 0.0, threads)
    process = subprocess.run([cli, "--time", "--objective", *extra], input=text, text=True,
                             capture_output=True)
    if process.returncode != 0:
        print(f"compare_pomegranate: FAIL: {cli} exited with {process.returncode} on dataset "
              f"'{dataset.name}':\n{process.stderr}")
        sys.exit(2)
    rows, objective, seconds = [], [], None
    for line in process.stdout.splitlines():
        words = line.split()
        if words[0] == "objective":
            objective.append(float(words[2]))
        elif words[0] == "time_s":
            seconds = float(words[1])
        else:
            rows.append((float(words[0]), float(words[1]), int(words[2]), float(words[3]),
                         float(words[4])))
    if len(rows) != len(dataset.cells):
        print(f"compare_pomegranate: FAIL: the CLI printed {len(rows)} cells for "
              f"{len(dataset.cells)}")
        sys.exit(2)
    return rows, objective, seconds


# ----------------------------------------------------------------------- the pomegranate side

def symbol(hits, misses):
    return f"h{hits}m{misses}"


def pomegranate_sequence(cell):
    first = cell[0][0]
    sequence = ["n"] * (cell[-1][0] - first + 2)
    for step, hits, misses in cell:
        sequence[step - first + 1] = symbol(hits, misses) if hits + misses else "n"
    return sequence


class Emissions:
    """The frozen emission tables of one dataset (one per state), scaled by kappa."""

    def __init__(self, dataset):
        symbols = sorted({(h, m) for cell in dataset.cells for _, h, m in cell if h + m})
        self.kappa = 1.0 / (2.0 * (len(symbols) + 1))  # each table's mass <= 1/2 before slack
        self.tables = []
        for state in (OCC, FREE):
            p = dataset.p_hit[state]
            table = {symbol(h, m): self.kappa * p ** h * (1.0 - p) ** m for h, m in symbols}
            table["n"] = self.kappa
            table["slack"] = 1.0 - sum(table.values())
            self.tables.append(table)

    def log_kappa(self):
        return math.log(self.kappa)


def build_model(dataset, emissions):
    model = pg.HiddenMarkovModel(name="cell")
    occ = pg.State(pg.DiscreteDistribution(dict(emissions.tables[OCC]), frozen=True), name="occ")
    free = pg.State(pg.DiscreteDistribution(dict(emissions.tables[FREE]), frozen=True),
                    name="free")
    model.add_states(occ, free)
    q = dataset.initial_p_occ
    model.add_transition(model.start, occ, q, pseudocount=START_PSEUDOCOUNT * q)
    model.add_transition(model.start, free, 1.0 - q, pseudocount=START_PSEUDOCOUNT * (1.0 - q))
    model.add_transition(occ, occ, 1.0 - dataset.p_fo0, pseudocount=EDGE_PSEUDOCOUNT)
    model.add_transition(occ, free, dataset.p_fo0, pseudocount=EDGE_PSEUDOCOUNT)
    model.add_transition(free, occ, dataset.p_of0, pseudocount=EDGE_PSEUDOCOUNT)
    model.add_transition(free, free, 1.0 - dataset.p_of0, pseudocount=EDGE_PSEUDOCOUNT)
    model.bake(merge="None")
    return model


def fit_exactly(model, sequence, m_steps):
    """Baum-Welch with exactly m_steps M-steps (and m_steps + 1 E-steps, the last one on the
    learned parameters, as runOfflineEm does); see the module docstring."""
    if m_steps == 0:
        return
    model.fit([sequence], algorithm="baum-welch", min_iterations=m_steps,
              max_iterations=m_steps, stop_threshold=math.inf, use_pseudocount=True,
              multiple_check_input=False, n_jobs=1)


def learned_params(model):
    matrix = model.dense_transition_matrix()
    names = [state.name for state in model.states]
    occ, free = names.index("occ"), names.index("free")
    return matrix[free, occ], matrix[occ, free]  # (p_of, p_fo)


def final_posterior_occ(model, sequence):
    names = [state.name for state in model.states]
    return model.predict_proba(sequence)[-1][names.index("occ")]


# ----------------------------------------------------------------- a plain numpy reference

def numpy_reference(dataset, cell, m_steps):
    """Step-by-step scaled Baum-Welch, no closed forms; returns (p_of, p_fo, log_lik)."""
    sequence = pomegranate_sequence(cell)
    first = cell[0][0]
    likelihood = np.ones((len(sequence), 2))
    for step, hits, misses in cell:
        likelihood[step - first + 1] = [p ** hits * (1 - p) ** misses for p in dataset.p_hit]
    p_of, p_fo = dataset.p_of0, dataset.p_fo0

    def forward_backward(p_of, p_fo):
        a_matrix = np.array([[1 - p_fo, p_fo], [p_of, 1 - p_of]])
        steps = len(sequence)
        alpha = np.zeros((steps, 2))
        scale = np.zeros(steps)
        alpha[0] = np.array([dataset.initial_p_occ, 1 - dataset.initial_p_occ]) * likelihood[0]
        scale[0] = alpha[0].sum()
        alpha[0] /= scale[0]
        for t in range(1, steps):
            alpha[t] = (alpha[t - 1] @ a_matrix) * likelihood[t]
            scale[t] = alpha[t].sum()
            alpha[t] /= scale[t]
        beta = np.ones((steps, 2))
        counts = np.zeros((2, 2))
        for t in range(steps - 1, 0, -1):
            counts += np.outer(alpha[t - 1], likelihood[t] * beta[t]) * a_matrix / scale[t]
            beta[t - 1] = a_matrix @ (likelihood[t] * beta[t]) / scale[t]
        return counts, float(np.log(scale).sum())

    for _ in range(m_steps):
        counts, _ = forward_backward(p_of, p_fo)
        p_fo = counts[OCC, FREE] / counts[OCC].sum()
        p_of = counts[FREE, OCC] / counts[FREE].sum()
    return p_of, p_fo, forward_backward(p_of, p_fo)[1]


# ---------------------------------------------------------------------------- the comparison

def check_cli_rejects_malformed(cli):
    """The CLI must refuse bad input with a message and a non-zero status."""
    header = "0.7 0.2 0.5 0.1 0.2 5 0 1\n"
    cases = {"empty input": "", "short header": "0.7 0.2 0.5 0.1 0.2 5 0\n",
             "no cells": header, "truncated cell": header + "2 1 1 0\n",
             "not a number": header + "1 1 x 0\n", "steps not increasing": header + "2 4 1 0 4 0 1\n",
             "bad sensor": "0.2 0.7 0.5 0.1 0.2 5 0 1\n1 1 1 0\n"}
    failures = []
    for name, text in cases.items():
        process = subprocess.run([cli], input=text, text=True, capture_output=True)
        if process.returncode == 0 or not process.stderr.strip():
            failures.append(f"the CLI accepted malformed input ({name}): status "
                            f"{process.returncode}, stderr {process.stderr!r}")
    return failures



def compare(cli, datasets, iterations):
    failures = check_cli_rejects_malformed(cli)
    total_cells = total_obs = 0
    worst = {"transition": 0.0, "log_likelihood": 0.0, "final_p_occ": 0.0,
             "objective": 0.0, "reference": 0.0}
    off_by_one = {iterations - 1: math.inf, iterations + 1: math.inf}
    started = time.time()
    for dataset in datasets:
        emissions = Emissions(dataset)
        rows, objective, _ = run_cli(cli, dataset, iterations, threads=1)
        rows_mt, _, _ = run_cli(cli, dataset, iterations, threads=2)
        if rows_mt != rows:
            failures.append(f"[{dataset.name}] results with threads=2 differ from threads=1")
        neighbours = {n: run_cli(cli, dataset, n)[0] for n in off_by_one}
        sum_log_likelihood = 0.0
        diff_off = {n: 0.0 for n in off_by_one}
        for index, cell in enumerate(dataset.cells):
            sequence = pomegranate_sequence(cell)
            model = build_model(dataset, emissions)
            fit_exactly(model, sequence, iterations)
            p_of, p_fo = learned_params(model)
            ours = rows[index]
            d_trans = max(abs(p_of - ours[0]), abs(p_fo - ours[1]))
            log_lik = model.log_probability(sequence) - len(sequence) * emissions.log_kappa()
            d_ll = abs(log_lik - ours[4])
            d_final = abs(final_posterior_occ(model, sequence) - ours[3])
            sum_log_likelihood += ours[4]
            worst["transition"] = max(worst["transition"], d_trans)
            worst["log_likelihood"] = max(worst["log_likelihood"], d_ll)
            worst["final_p_occ"] = max(worst["final_p_occ"], d_final)
            for n, other in neighbours.items():
                diff_off[n] = max(diff_off[n], abs(p_of - other[index][0]),
                                  abs(p_fo - other[index][1]))
            problems = []
            if not d_trans <= TOLERANCE:
                problems.append(f"transitions differ by {d_trans:.3g}")
            if not d_ll <= TOLERANCE:
                problems.append(f"log-likelihood differs by {d_ll:.3g}")
            if not d_final <= TOLERANCE:
                problems.append(f"final p(occ) differs by {d_final:.3g}")
            if ours[2] != iterations:
                problems.append(f"the CLI reports {ours[2]} iterations, not {iterations}")
            # The third opinion: on a sample of cells, and on every cell that mismatched.
            if problems or index % 25 == 0:
                ref = numpy_reference(dataset, cell, iterations)
                d_ref = max(abs(ref[0] - p_of), abs(ref[1] - p_fo), abs(ref[2] - log_lik))
                worst["reference"] = max(worst["reference"], d_ref)
                if not d_ref <= TOLERANCE:
                    problems.append(f"pomegranate differs from the numpy reference by {d_ref:.3g} "
                                    "(harness problem)")
                if problems:
                    d_ours = max(abs(ref[0] - ours[0]), abs(ref[1] - ours[1]),
                                 abs(ref[2] - ours[4]))
                    problems.append(f"numpy reference vs CLI: {d_ours:.3g}")
            if problems:
                failures.append(
                    f"[{dataset.name}] cell {index} ({len(cell)} observations, "
                    f"{len(sequence)} steps): " + "; ".join(problems) + "\n"
                    f"    CLI:         p_of={ours[0]:.17g} p_fo={ours[1]:.17g} "
                    f"loglik={ours[4]:.17g} final_p_occ={ours[3]:.17g}\n"
                    f"    pomegranate: p_of={p_of:.17g} p_fo={p_fo:.17g} loglik={log_lik:.17g}\n"
                    f"    input line:  {len(cell)} " + " ".join(f"{s} {h} {m}" for s, h, m in cell))
        # The result's objective after N M-steps is the sum of the cells' log-likelihoods.
        if len(objective) == iterations + 1:
            d_obj = abs(objective[-1] - sum_log_likelihood)
            worst["objective"] = max(worst["objective"], d_obj)
            if not d_obj <= TOLERANCE * max(1.0, len(dataset.cells) / 10):
                failures.append(f"[{dataset.name}] objective[{iterations}] = {objective[-1]!r} "
                                f"but the cells' log-likelihoods sum to {sum_log_likelihood!r}")
        else:
            failures.append(f"[{dataset.name}] the CLI's objective has {len(objective)} entries, "
                            f"expected {iterations + 1}")
        for n in off_by_one:
            off_by_one[n] = min(off_by_one[n], diff_off[n])
        total_cells += len(dataset.cells)
        total_obs += dataset.observed_steps()
        print(f"dataset {dataset.name}: {len(dataset.cells)} cells, {dataset.observed_steps()} "
              f"observed steps, kappa={emissions.kappa:.4g}")
    # The meaning of N: pomegranate's N M-steps must differ clearly from our N - 1 and N + 1.
    for n, diff in off_by_one.items():
        print(f"sensitivity: pomegranate with {iterations} M-steps vs the CLI with {n}: "
              f"max transition difference {diff:.3g} (must be > {100 * TOLERANCE:g})")
        if not diff > 100 * TOLERANCE:
            failures.append(f"the check cannot tell {iterations} from {n} iterations "
                            f"(max difference {diff:.3g}): the data do not exercise EM")
    print(f"{total_cells} cells, {total_obs} observed steps, {iterations} M-steps each, "
          f"{time.time() - started:.1f} s")
    for key, value in worst.items():
        print(f"max |difference| {key:15s} {value:.3g}")
    if failures:
        print(f"compare_pomegranate: FAIL ({len(failures)} problems, tolerance {TOLERANCE:g}):")
        for line in failures[:20]:
            print(line)
        if len(failures) > 20:
            print(f"... and {len(failures) - 20} more")
        return 1
    print(f"compare_pomegranate: OK, the offline EM matches pomegranate to {TOLERANCE:g}")
    return 0


def benchmark(cli, cells, steps, iterations, seed):
    rng = np.random.default_rng(seed)
    data = [simulate_cell(rng, (0.7, 0.2), 0.5, steps, 6, 2, int(rng.integers(0, 100)))
            for _ in range(cells)]
    dataset = Dataset("benchmark", 0.7, 0.2, 0.5, 0.1, 0.2, data)
    work = dataset.observed_steps() * iterations
    symbols = sum(len(pomegranate_sequence(cell)) for cell in data)
    print(f"benchmark: {cells} cells x {steps} observed steps ({symbols} steps incl. unobserved), "
          f"{iterations} iterations, one thread")
    cli_seconds = min(run_cli(cli, dataset, iterations, threads=1)[2] for _ in range(3))
    emissions = Emissions(dataset)
    sequences = [pomegranate_sequence(cell) for cell in data]
    started = time.perf_counter()
    models = [build_model(dataset, emissions) for _ in data]
    build_seconds = time.perf_counter() - started
    started = time.perf_counter()
    for model, sequence in zip(models, sequences):
        fit_exactly(model, sequence, iterations)
    pg_seconds = time.perf_counter() - started
    cli_rate = work / cli_seconds
    pg_rate = work / pg_seconds
    print(f"  offline EM (C++ runOfflineEm, best of 3): {cli_seconds:.3f} s -> {cli_rate:.4g} observed "
          "cell-steps/s per iteration")
    print(f"  pomegranate fit:               {pg_seconds:.3f} s -> {pg_rate:.4g} observed "
          f"cell-steps/s per iteration (model construction {build_seconds:.2f} s not counted)")
    print(f"  ratio C++ / pomegranate: {cli_rate / pg_rate:.1f}x")
    # pomegranate's best case: one fit() over all sequences (one shared model; the same
    # forward-backward work per step, without the per-cell Python calls).
    shared = build_model(dataset, emissions)
    started = time.perf_counter()
    shared.fit(sequences, algorithm="baum-welch", min_iterations=iterations,
               max_iterations=iterations, stop_threshold=math.inf, use_pseudocount=True,
               multiple_check_input=False, n_jobs=1)
    shared_seconds = time.perf_counter() - started
    print(f"  (pomegranate, one fit of one shared model over all cells: {shared_seconds:.3f} s -> "
          f"{work / shared_seconds:.4g} cell-steps/s per iteration; it costs "
          f"{1e9 * shared_seconds / (symbols * (iterations + 1)):.0f} ns per step incl. "
          f"unobserved steps per E-step, the C++ {1e9 * cli_seconds / (work + dataset.observed_steps()):.0f} "
          f"ns per observed step)")
    return 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("cli", help="path of the offline_em_cli test tool")
    parser.add_argument("--cells", type=int, default=200, help="cells per dataset")
    parser.add_argument("--iterations", type=int, default=25, help="M-steps on both sides")
    parser.add_argument("--seed", type=int, default=20240611)
    parser.add_argument("--benchmark", action="store_true",
                        help="time pomegranate against the CLI instead of comparing")
    parser.add_argument("--bench-cells", type=int, default=2000)
    parser.add_argument("--bench-steps", type=int, default=200)
    parser.add_argument("--bench-iterations", type=int, default=20)
    args = parser.parse_args()
    if args.iterations < 1:
        parser.error("--iterations must be >= 1 (the check compares N with N - 1)")
    if args.benchmark:
        return benchmark(args.cli, args.bench_cells, args.bench_steps, args.bench_iterations,
                         args.seed)
    return compare(args.cli, make_datasets(args.seed, args.cells), args.iterations)


if __name__ == "__main__":
    sys.exit(main())
