"""The `reshader-train` command: one subcommand per stage of the toolchain.

Subcommand modules are imported only when chosen, so that `render` works without
PyTorch installed and `train` works without Mitsuba.
"""

import argparse
import importlib
import sys

# (name, module, one-line help). Each module defines add_arguments(parser) and run(args).
COMMANDS = [
    (
        "render",
        "reshader_train.render.command",
        "render input/reshaded dataset examples (Mitsuba 3)",
    ),
    ("sheet", "reshader_train.render.sheet", "contact sheet PNG of a rendered dataset"),
    (
        "headroom",
        "reshader_train.render.headroom",
        "how much any network could gain: input vs input + noise-free change, re-rendered",
    ),
    (
        "import",
        "reshader_train.from_onnx",
        "checkpoint from an exported fp32 encoder/decoder pair (e.g. to add a dead zone)",
    ),
    ("train", "reshader_train.train", "train the reshading network (single process or torchrun)"),
    (
        "average",
        "reshader_train.average",
        "checkpoint whose weights are the mean of several (e.g. a run's last ones)",
    ),
    (
        "field-fit",
        "reshader_train.field_fit",
        "how much a lobe head could gain: fields fitted per example, scored on a held-out camera",
    ),
    (
        "teacher",
        "reshader_train.teacher",
        "a lobe head's fields fitted to every camera of each example, as targets for train",
    ),
    (
        "teacher-check",
        "reshader_train.teacher_check",
        "how a taught lobes or lobes-slide network's fields compare with its teacher's: where "
        "and how much light it moves (amplitudes, shares of the pixel's light, axes, sharpness; "
        "or the sliding layer's fraction)",
    ),
    ("evaluate", "reshader_train.evaluate", "PSNR/SSIM of input vs reshaded on held-out data"),
    (
        "compare",
        "reshader_train.compare",
        "two models' evaluate --json on the same views, view by view: where one gains or loses",
    ),
    ("export", "reshader_train.export", "ONNX models (fp32/fp16/int8, single/split) + manifests"),
    ("quantize", "reshader_train.quantize", "quantisation-aware int8 fine-tuning of a checkpoint"),
    ("fixture", "reshader_train.fixture", "tiny model + parity data for the runtime's tests"),
    (
        "examples",
        "reshader_train.examples",
        "held-out examples as 8-bit PNGs with PyTorch's PSNR, for the runtime's tests",
    ),
    ("convert-depth", "reshader_train.depthconv.command", "Caffe2 depth net -> ONNX int8, fp32"),
    (
        "train-depth",
        "reshader_train.depthtune.train",
        "fine-tune the depth network on rendered photos with true depth",
    ),
    (
        "export-depth",
        "reshader_train.depthtune.export",
        "a train-depth checkpoint as an fp32 ONNX depth model with its manifest",
    ),
]


def build_parser(chosen: str | None = None) -> argparse.ArgumentParser:
    """The parser, with the arguments of `chosen` (every subcommand's when None).

    Importing a subcommand's module can take seconds (PyTorch, ONNX): a recipe that
    calls `render` hundreds of times to resume a data set should not pay them each time.
    """
    parser = argparse.ArgumentParser(
        prog="reshader-train",
        description="Render training data, train the reshading network, export ONNX models.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module, help_text in COMMANDS:
        p = sub.add_parser(name, help=help_text, description=help_text)
        p.set_defaults(_module=module)
        if chosen not in (None, name):
            continue
        try:
            importlib.import_module(module).add_arguments(p)
        except ImportError as err:
            p.set_defaults(_import_error=err)
    return parser


def chosen_command(argv: list[str]) -> str | None:
    """The subcommand `argv` names (its first word, as argparse reads it), if any."""
    names = {name for name, _, _ in COMMANDS}
    first = next((a for a in argv if not a.startswith("-")), None)
    return first if first in names else None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = build_parser(chosen_command(argv)).parse_args(argv)
    err = getattr(args, "_import_error", None)
    if err is not None:
        print(f"reshader-train {args.command}: missing dependency: {err}", file=sys.stderr)
        return 2
    return int(importlib.import_module(args._module).run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
