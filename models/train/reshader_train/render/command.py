"""`reshader-train render`: render input/reshaded dataset examples with Mitsuba 3."""

import os
import statistics
import sys
import time

from .example import RenderSettings, example_id, is_complete, render_example


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size {text!r}: expected WIDTHxHEIGHT, e.g. 256x192") from None
    if w < 8 or h < 8:
        raise ValueError(f"--size {text!r}: width and height must be at least 8")
    return w, h


def _shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard {text!r}: expected I/N, e.g. 3/16") from None
    if not (n >= 1 and 0 <= i < n):
        raise ValueError(f"--shard {text!r}: need 0 <= I < N")
    return i, n


def add_arguments(parser) -> None:
    parser.add_argument("--out", required=True, help="dataset folder (created if missing)")
    parser.add_argument(
        "--scenes",
        default="procedural",
        help="'procedural' (default: rooms and tabletops of every material), "
        "'procedural:highlights' (curved glossy objects on tabletops under a sun and orbs, "
        "seen from close by), 'procedural:studio' (the same under a dim uniform "
        "environment, lit by the sun and orbs), 'procedural:products' (product shots on "
        "sweeps and counters under studio softboxes, strip lights, windows and skies; wood, "
        "car paint, stone, metals, ceramics, plastics, some glass), 'procedural:rooms' "
        "(rooms with varnished floors, counters, tables and cars, lit by windows and "
        "ceiling panels), 'procedural:diffuse' (both with every material Lambertian: "
        "nothing changes between views), 'analytic' (spheres, boxes and cylinders under "
        "sky, sun, softbox and orb lights, shaded in closed form by numpy without Mitsuba: "
        "noise-free and several times faster; --spp is sub-pixel samples, at most 3x3) or "
        "a Mitsuba 3 scene file (.xml)",
    )
    parser.add_argument("--count", type=int, required=True, help="examples in the dataset")
    parser.add_argument("--seed", type=int, default=0, help="dataset seed (default 0)")
    parser.add_argument("--size", default="256x192", help="WIDTHxHEIGHT (default 256x192)")
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel (default 64)")
    parser.add_argument(
        "--shard",
        default="0/1",
        help="render only indices I, I+N, I+2N, ... (I/N, I counts from 0; default 0/1)",
    )
    parser.add_argument("--threads", type=int, default=None, help="Dr.Jit threads (default all)")
    parser.add_argument(
        "--radius", default="0.1,0.3", help="novel camera shell radii MIN,MAX (default 0.1,0.3)"
    )
    parser.add_argument(
        "--change-seeds",
        type=int,
        default=1,
        help="ground truth = input + the mean (reshaded - input) over K sample seeds, which "
        "keeps the input's noise and divides the change's variance by K (default 1: the "
        "reshaded render of the input's seed); costs 2 more renders per extra seed",
    )
    parser.add_argument(
        "--targets",
        type=int,
        default=1,
        help="reshaded targets per example, each from its own novel camera (default 1). The "
        "first is reshaded.exr as always; the others are reshaded-K.exr and mask-K.png, "
        "listed in meta.json's extra_targets, so that one network pass in training is "
        "supervised at several cameras (train --targets-per-example). Mitsuba scenes reuse "
        "the example's input renders and compiled kernels: a further target costs its "
        "reshaded renders alone (about a fifth of an example's time)",
    )
    parser.add_argument(
        "--input-only",
        action="store_true",
        help="write only input.exr, depth.exr and meta.json (no reshaded or novel render, "
        "no mask; meta.json says input_only): examples for training a depth network "
        "(train-depth), about a third of the cost. Mitsuba scenes only",
    )
    parser.add_argument(
        "--layouts",
        type=int,
        default=0,
        help="procedural: example i re-dresses layout i mod K (geometry, sky and area lights "
        "fixed; materials, orbs and cameras new), as the paper re-dresses its 9 scenes "
        "(default 0: a new scene per example)",
    )
    parser.add_argument(
        "--layout-seed",
        type=int,
        default=0,
        help="seed of the layouts, independent of --seed so that train and validation "
        "sets share them (default 0)",
    )
    parser.add_argument(
        "--randomize-materials",
        action="store_true",
        help="scene files: replace every material by a random one per example",
    )
    parser.add_argument(
        "--orbs", type=int, default=None, help="scene files: add this many random emissive orbs"
    )


def _source(args):
    from .sources import ProceduralSource, SceneFileSource

    if args.scenes == "procedural" or args.scenes.startswith("procedural:"):
        if args.randomize_materials or args.orbs is not None:
            raise ValueError("--randomize-materials and --orbs apply to scene files only")
        return ProceduralSource(
            args.scenes.partition(":")[2] or "mixed", args.layouts, args.layout_seed
        )
    if args.layouts:
        raise ValueError("--layouts applies to procedural scenes only")
    return SceneFileSource(args.scenes, args.randomize_materials, args.orbs or 0)


def parse_settings(args) -> RenderSettings:
    width, height = _size(args.size)
    try:
        r_min, r_max = (float(v) for v in args.radius.split(","))
    except ValueError:
        raise ValueError(f"--radius {args.radius!r}: expected MIN,MAX, e.g. 0.1,0.3") from None
    if not 0 <= r_min <= r_max:
        raise ValueError(f"--radius {args.radius!r}: need 0 <= MIN <= MAX")
    if args.spp < 1 or args.count < 0:
        raise ValueError("--spp must be >= 1 and --count >= 0")
    change_seeds = getattr(args, "change_seeds", 1)
    if change_seeds < 1:
        raise ValueError(f"--change-seeds {change_seeds}: need at least 1")
    targets = getattr(args, "targets", 1)
    if targets < 1:
        raise ValueError(f"--targets {targets}: need at least 1")
    input_only = getattr(args, "input_only", False)
    return RenderSettings(width, height, args.spp, r_min, r_max, change_seeds, targets, input_only)


def summarize(seconds: list[float], skipped: int, failed: list) -> str:
    lines = [f"rendered {len(seconds)} examples, skipped {skipped} already complete"]
    if seconds:
        lines.append(
            f"seconds per example: mean {statistics.mean(seconds):.2f}, "
            f"median {statistics.median(seconds):.2f}, min {min(seconds):.2f}, "
            f"max {max(seconds):.2f}, total {sum(seconds):.0f}"
        )
    if failed:
        lines.append(f"FAILED {len(failed)}: " + ", ".join(f"{i} ({e})" for i, e in failed[:10]))
    return "\n".join(lines)


def release_caches() -> None:
    """Drop the compiled kernels of the previous scene: every scene compiles its own, and
    a long job would otherwise keep thousands of them in memory."""
    import gc

    import drjit as dr

    gc.collect()
    dr.flush_kernel_cache()
    dr.flush_malloc_cache()


class AnalyticSource:
    """The numpy family (`analytic`): no Mitsuba, nothing to load or release."""

    name = "analytic"

    def load(self) -> None:
        """Nothing to load."""

    def render(self, out: str, seed: int, index: int, settings: RenderSettings) -> None:
        from . import analytic

        analytic.render_example(out, seed, index, settings)


class MitsubaRenderer:
    """A Mitsuba scene source; frees each scene's kernels after it. Mitsuba loads in
    `load`, apart from the flags' checks, because loading it takes seconds that a resumed
    job with nothing left to render should not spend (a recipe checks every round)."""

    def __init__(self, args):
        self.source = _source(args)
        self.name = self.source.name
        self.threads = args.threads
        self.mi = None

    def load(self) -> None:
        from .mitsuba_env import load_mitsuba

        self.mi = load_mitsuba(self.threads)
        self.source.prepare(self.mi)

    def render(self, out: str, seed: int, index: int, settings: RenderSettings) -> None:
        try:
            render_example(self.mi, self.source, out, seed, index, settings)
        finally:
            release_caches()


def _renderer(args):
    if args.scenes == "analytic":
        for flag in ("layouts", "randomize_materials", "orbs"):
            if getattr(args, flag):
                raise ValueError(f"--{flag.replace('_', '-')} does not apply to analytic scenes")
        if args.change_seeds != 1:
            raise ValueError("analytic scenes have no sampling noise: --change-seeds must be 1")
        if getattr(args, "input_only", False):
            raise ValueError("--input-only applies to Mitsuba scenes only")
        return AnalyticSource()
    if getattr(args, "input_only", False) and getattr(args, "targets", 1) != 1:
        raise ValueError("--input-only renders no reshaded target: --targets must be 1")
    return MitsubaRenderer(args)


def run(args) -> int:
    from tqdm import tqdm

    from .mitsuba_env import LlvmNotFound

    try:
        settings = parse_settings(args)
        shard, shards = _shard(args.shard)
        source = _renderer(args)
        indices = range(shard, args.count, shards)
        todo = [i for i in indices if not is_complete(args.out, example_id(args.seed, i))]
        if todo:
            source.load()
    except (ValueError, FileNotFoundError, LlvmNotFound) as err:
        print(f"reshader-train render: {err}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    skipped = len(indices) - len(todo)
    print(
        f"render: {source.name} -> {args.out}, seed {args.seed}, shard {shard}/{shards}: "
        f"{len(todo)} to render, {skipped} already complete; "
        f"{settings.width}x{settings.height} at {settings.spp} spp"
        + (f", change over {settings.change_seeds} seeds" if settings.change_seeds > 1 else "")
        + (f", {settings.targets} targets per example" if settings.targets > 1 else "")
        + (", input and depth only" if settings.input_only else ""),
        flush=True,
    )
    seconds, failed = [], []
    bar = tqdm(todo, unit="ex", dynamic_ncols=True, mininterval=5)
    for index in bar:
        start = time.perf_counter()
        try:
            source.render(args.out, args.seed, index, settings)
        except RuntimeError as err:  # one bad example must not stop a long job
            failed.append((index, str(err).splitlines()[0]))
            print(f"example {index} failed: {err}", file=sys.stderr, flush=True)
            continue
        seconds.append(time.perf_counter() - start)
        bar.set_postfix(s_per_ex=f"{statistics.mean(seconds):.1f}")
    print(summarize(seconds, skipped, failed), flush=True)
    return 1 if failed else 0
