"""``bench NAME --compare-with REF``: this tree's benchmark and a reference commit's, alternately in one
invocation, so that every ratio is made of figures from the same machine at the same time.

REF is checked out with ``git worktree add --detach`` into a temporary folder as ``…/mogaface`` and
removed afterwards; each measurement is a fresh Python process whose ``PYTHONPATH`` holds the parent
of one of the two trees (this one through a link named ``mogaface``), so ``import mogaface`` is that
tree's code. The two sides take turns, the first side alternating between rounds, and each run
records the 1-minute load average before and after. Ratios are this tree's figure over REF's
(times: below 1 is faster; steps per second: above 1 is faster), medians over the rounds.
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile

PACKAGE = "mogaface"
BENCHMARKS = ("splat", "step", "train")
MARK = "@@bench-json@@"
SPLAT_CONFIGS = ((10_000, 256), (30_000, 256), (30_000, 512), (100_000, 512))
SPLAT_QUICK_CONFIGS = ((10_000, 256), (30_000, 512))


def repository_root() -> str:
    """The git work tree this package is in (the package is the repository root)."""
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    done = subprocess.run(["git", "-C", here, "rev-parse", "--show-toplevel"], capture_output=True, text=True)
    if done.returncode:
        raise RuntimeError(f"--compare-with needs a git checkout; {here} is not one ({done.stderr.strip()})")
    return done.stdout.strip()


@contextlib.contextmanager
def checkouts(root: str, ref: str, package: str = PACKAGE):
    """``(head_path, ref_path, ref_commit)``: folders to put on ``PYTHONPATH`` so that ``import package``
    is the working tree at ``root``, or commit ``ref`` of its repository; the worktree of ``ref`` is
    removed on exit."""
    done = subprocess.run(["git", "-C", root, "rev-parse", "--verify", f"{ref}^{{commit}}"],
                          capture_output=True, text=True)
    if done.returncode:
        raise ValueError(f"--compare-with: {ref!r} is not a commit of {root} ({done.stderr.strip()})")
    commit = done.stdout.strip()
    with tempfile.TemporaryDirectory(prefix="mogaface-compare-") as folder:
        head = os.path.join(folder, "head")
        os.makedirs(head)
        os.symlink(root, os.path.join(head, package))
        reference = os.path.join(folder, "ref")
        tree = os.path.join(reference, package)
        subprocess.run(["git", "-C", root, "worktree", "add", "--detach", "--quiet", tree, commit],
                       check=True, capture_output=True, text=True)
        try:
            yield head, reference, commit
        finally:
            subprocess.run(["git", "-C", root, "worktree", "remove", "--force", tree], capture_output=True)
            subprocess.run(["git", "-C", root, "worktree", "prune"], capture_output=True)


def run_side(path: str, module: str, function: str, args: list, kwargs: dict, patch: dict) -> dict:
    """``module.function(*args, **kwargs)`` of the tree on ``path``, in a fresh process, after setting the
    module's attributes in ``patch``; its JSON."""
    env = dict(os.environ)
    env["PYTHONPATH"] = path + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    env.setdefault("OMP_WAIT_POLICY", "PASSIVE")
    code = (f"import json, {PACKAGE}, importlib; m = importlib.import_module({module!r}); "
            f"[setattr(m, k, v) for k, v in {patch!r}.items()]; r = m.{function}(*{args!r}, **{kwargs!r}); r['code'] = {PACKAGE}.__file__; "
            f"print({MARK!r} + json.dumps(r))")
    load = os.getloadavg()[0]
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=path)
    if done.returncode:
        raise RuntimeError(f"benchmark run under {path} failed:\n{done.stderr[-4000:]}")
    line = [x for x in done.stdout.splitlines() if x.startswith(MARK)][-1]
    result = json.loads(line[len(MARK):])
    result["load_average_1min_before_after"] = [round(load, 2), round(os.getloadavg()[0], 2)]
    return result


def _jobs(name: str, threads: int, quick: bool, options: dict) -> list:
    """``(label, module, function, args, kwargs, patch)`` per measurement; splat: one per configuration
    (its child function, so configurations alternate too), without the torch reference."""
    if name == "splat":
        configs = SPLAT_QUICK_CONFIGS if quick else SPLAT_CONFIGS
        repeats = 5 if quick else 11
        return [(f"{n}@{size}", f"{PACKAGE}.bench.splat", "_child",
                 [{"n": n, "size": size, "threads": threads, "repeats": repeats}], {}, {"REFERENCE_PAIRS": 0})
                for n, size in configs]
    return [(name, f"{PACKAGE}.bench.{name}", "run", [], {"threads": threads, "quick": quick, **options}, {})]


def figures(name: str, result: dict) -> dict:
    """The figures a ratio is taken of, by name, from one run's report."""
    out = {}
    if name == "splat":
        fwd, both = result["forward_ms"], result["fwd_bwd_ms"]
        return {"forward_ms": fwd, "backward_ms": round(both - fwd, 2), "fwd_bwd_ms": both,
                "backward_over_forward": round((both - fwd) / fwd, 3)}
    if "results" not in result:  # train --scale real: one result
        return {"it_s": result["it_s"]}
    for row in result["results"]:
        key = f"{row['variant']} {row['gaussians']}"
        if "it_s" in row:
            out[f"{key}: it_s"] = row["it_s"]
        if "step_ms" in row:
            out[f"{key}: step_ms"] = row["step_ms"]
            for stage, ms in row["stages_ms"].items():
                out[f"{key}: {stage}"] = ms
    return out


def run(name: str, ref: str, threads: int = 2, quick: bool = False, rounds: int = 2, **options) -> dict:
    if name not in BENCHMARKS:
        raise ValueError(f"--compare-with applies to the {', '.join(BENCHMARKS)} benchmarks, not {name!r}")
    if rounds < 1:
        raise ValueError("--rounds must be at least 1")
    jobs = _jobs(name, threads, quick, options)
    runs = {label: {"head": [], "ref": []} for label, *_ in jobs}
    with checkouts(repository_root(), ref) as (head, reference, commit):
        paths = {"head": head, "ref": reference}
        for round_ in range(rounds):
            for label, module, function, args, kwargs, patch in jobs:
                for side in (("head", "ref") if round_ % 2 == 0 else ("ref", "head")):
                    result = run_side(paths[side], module, function, args, kwargs, patch)
                    runs[label][side].append(result)
    table = {}
    for label, sides in runs.items():
        head_figures = [figures(name, r) for r in sides["head"]]
        ref_figures = [figures(name, r) for r in sides["ref"]]
        rows = {}
        for key in head_figures[0]:
            if not all(key in f for f in head_figures + ref_figures):
                continue
            h = statistics.median(f[key] for f in head_figures)
            r = statistics.median(f[key] for f in ref_figures)
            rows[key] = {"head": round(h, 3), "ref": round(r, 3), "ratio": round(h / r, 3) if r else None}
        loads = [x for side in sides.values() for res in side for x in res["load_average_1min_before_after"]]
        table[label] = {"figures": rows, "load_average_1min": [min(loads), max(loads)]}
    return {
        "benchmark": name,
        "compare_with": ref,
        "ref_commit": commit,
        "rounds": rounds,
        "threads": threads,
        "quick": quick,
        "options": options,
        "machine": {"cpu_count": os.cpu_count(), "platform": platform.platform()},
        "note": "ratio = this tree / REF, medians over rounds run alternately in this invocation; times below 1 "
                "and it_s above 1 mean this tree is faster; load_average_1min is the range over the runs",
        "ratios": table,
        "runs": runs,
    }
