"""The numbers of two summary.json files, leaf by leaf, without what depends on the
machine (times, dates, file names, which tasks were reused)."""
from __future__ import annotations

import re

#: keys whose values are times, dates, paths or bookkeeping, not results
NOT_NUMBERS = re.compile(r"(^|/)(time|total_time|elapsed|finished|stages|figures|options|"
                         r"critical_path|cached|gait_file|simulate_args|solver_stats|"
                         r"compute_time|build|solve_time|polish_time|ipopt_timing|"
                         r"cache_file|folder|seconds)(/|\[|$)")


def leaves(obj, path=""):
    """(path, value) of every leaf of a JSON object."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from leaves(v, f"{path}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from leaves(v, f"{path}[{i}]")
    else:
        yield path, obj


def differences(a: dict, b: dict, rtol: float = 0.0) -> list:
    """The leaves of two summaries that differ (beyond ``rtol`` for numbers), and those
    only one has, ignoring :data:`NOT_NUMBERS`."""
    la = {k: v for k, v in leaves(a) if not NOT_NUMBERS.search(k)}
    lb = {k: v for k, v in leaves(b) if not NOT_NUMBERS.search(k)}
    out = [(k, la.get(k), lb.get(k)) for k in sorted(set(la) ^ set(lb))]
    for k in sorted(set(la) & set(lb)):
        x, y = la[k], lb[k]
        num = isinstance(x, (int, float)) and isinstance(y, (int, float)) \
            and not isinstance(x, bool)
        if num and abs(x - y) <= rtol * max(abs(x), abs(y)):
            continue
        if x != y:
            out.append((k, x, y))
    return out
