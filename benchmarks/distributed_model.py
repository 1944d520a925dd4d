"""The scaling model of the distributed benchmark (``predict``): T(W) of one processor on W workers of
1 thread, by parts, from measured task times and transfer sizes (docs/distributed.md)."""

from __future__ import annotations

import heapq
import math
import statistics


def lpt_makespan(durations: list[float], workers: int) -> float:
    """Longest-processing-time-first list scheduling over ``workers``: the finishing time of the busiest."""
    loads = [0.0] * max(1, workers)
    for duration in sorted(durations, reverse=True):
        heapq.heappush(loads, heapq.heappop(loads) + duration)
    return max(loads)


def list_makespan(durations: list[float], workers: int) -> float:
    """Greedy list scheduling in the given order (each task to the worker free first), as a pool or
    Dask hands out tasks submitted in that order."""
    loads = [0.0] * max(1, workers)
    for duration in durations:
        heapq.heappush(loads, heapq.heappop(loads) + duration)
    return max(loads)


def broadcast_hops(workers: int) -> int:
    """Scene transfers on the critical path of ``Client.scatter(broadcast=True)``: client -> scheduler ->
    one worker (2), then Dask's replicate tree copy, where each holder sends to up to 2 new workers a
    generation (``Scheduler.replicate``, branching_factor 2): a generation costs 2 transfers from the
    busiest holder, 1 when each holder sends one copy."""
    hops, holders = 2, 1
    while holders < workers:
        new = min(workers - holders, 2 * holders)
        hops += math.ceil(new / holders)
        holders += new
    return hops


def map_chunks(count: int, workers: int, chunk_size: int | None = None) -> list[tuple[int, int]]:
    """The (lo, hi) chunks DaskChunks cuts a map of ``count`` items into on ``workers`` workers."""
    from usdbake.core.chunks import chunk_bounds
    from usdbake.farm.chunks import MIN_CHUNK_ITEMS, TASKS_PER_WORKER

    size = chunk_size or max(MIN_CHUNK_ITEMS, math.ceil(count / (TASKS_PER_WORKER * workers)))
    return chunk_bounds(count, size) or [(0, 0)]


def first_tasks(run: dict) -> dict[str, int]:
    """{worker: index of its first task} (by compute start): the task that built the worker's BVH."""
    first: dict[str, int] = {}
    for index, task in enumerate(run["tasks"]):
        if task["worker"] not in first or task["start"] < run["tasks"][first[task["worker"]]]["start"]:
            first[task["worker"]] = index
    return first


def worker_setup_seconds(run: dict) -> float:
    """What a worker's first task of a scene costs beyond its compute (the BVH build, the scene's first
    use): its time less the median per-item time of the other tasks of its map times its items; the
    slowest worker's (they set up at once)."""
    excess = []
    for index in first_tasks(run).values():
        task = run["tasks"][index]
        others = [t["seconds"] / t["items"] for k, t in enumerate(run["tasks"])
                  if t["map"] == task["map"] and k != index and t["items"]]
        excess.append(task["seconds"] - (statistics.median(others) * task["items"] if others else 0.0))
    return max(excess, default=0.0)


def per_task_compute(profile: dict, coarse: dict) -> float:
    """Seconds of a task's compute that do not depend on its items (dispatch to the worker's thread,
    arrays and launch set-up): the same maps run on 1 worker in many and in few chunks differ by this
    much per extra task."""
    def compute(run):
        return sum(t["seconds"] for t in run["tasks"]) - worker_setup_seconds(run)

    extra = len(profile["tasks"]) - len(coarse["tasks"])
    return max(0.0, (compute(profile) - compute(coarse)) / extra) if extra > 0 else 0.0


def profile_maps(run: dict, setup: float) -> list[dict]:
    """Per map of a profile run: its item count and its chunks' compute seconds (each spread evenly over
    its items, ``recut``); the first task of each worker less the set-up time ``setup``."""
    firsts = set(first_tasks(run).values())
    maps = []
    for token in run["maps"]:
        pieces = sorted((task["first"], task["first"] + task["items"],
                         max(task["seconds"] - (setup if index in firsts else 0.0), 0.0))
                        for index, task in enumerate(run["tasks"]) if task["map"] == token)
        maps.append({"count": pieces[-1][1], "pieces": pieces})
    return maps


def recut(profile: dict, lo: int, hi: int, fixed: float) -> float:
    """Compute seconds of a task of items lo .. hi - 1 of a profiled map: ``fixed`` (per_task_compute)
    plus each profile chunk's time beyond ``fixed`` spread evenly over its items."""
    total = fixed
    for a, b, seconds in profile["pieces"]:
        overlap = min(hi, b) - max(lo, a)
        if overlap > 0:
            total += max(seconds - fixed, 0.0) * overlap / max(b - a, 1)
    return total


def predict(maps: list[dict], workers: int, c: dict) -> dict:
    """T(W) of one processor on ``workers`` workers of 1 thread, by parts (seconds).

    serial: the processor's time outside its maps in process (numpy between passes), and the BVH the
    client builds for applies(); scatter: the scene's pickled bytes (and any large setting a map
    scatters) x broadcast_hops / bandwidth; bvh:
    one set-up per worker (first-task excess: BVH build), all at once; compute: per map, one round
    trip + the LPT makespan of its chunks (compute re-cut from the profile, with its fixed part per
    task, + each task's worker time outside compute), at least tasks x the scheduler's time per task;
    transfer: items, results and each task's settings at the gather bandwidth.
    """
    compute, tasks = 0.0, 0
    for profile in maps:
        bounds = map_chunks(profile["count"], workers, c.get("chunk_size"))
        outside = max(c["overhead_per_task_s"] - c["noop_compute_s"], 0.0)  # a task's worker time outside compute
        durations = [recut(profile, lo, hi, c["per_task_compute_s"]) + outside for lo, hi in bounds]
        compute += c["round_trip_s"] + max(lpt_makespan(durations, workers),
                                           len(bounds) * c["scheduler_per_task_s"])
        tasks += len(bounds)
    parts = {
        "serial": c["serial_seconds"] + c["client_bvh_seconds"],
        "scatter": (c["scene_pickled_bytes"] + c["setting_scatter_bytes"]) * broadcast_hops(workers)
        / c["scatter_bytes_per_s"],
        "bvh": c["worker_bvh_seconds"],
        "compute": compute,
        "transfer": (c["item_bytes"] + c["result_bytes"] + tasks * c["static_bytes_per_task"])
        / c["gather_bytes_per_s"],
    }
    return {"workers": workers, "tasks": tasks, "seconds": sum(parts.values()), **parts}
