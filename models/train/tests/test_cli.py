"""The command line: each subcommand's arguments, and only its modules loaded."""

import subprocess
import sys

from reshader_train import cli


def test_the_chosen_command_is_the_first_word():
    assert cli.chosen_command(["render", "--out", "x", "--count", "3"]) == "render"
    assert cli.chosen_command(["-h"]) is None
    assert cli.chosen_command(["nonsense"]) is None


def test_render_loads_neither_torch_nor_onnx():
    # A recipe resuming a data set calls `render` once per family and round: importing
    # PyTorch each time cost seconds per call where the render itself had nothing to do.
    code = (
        "import sys; from reshader_train import cli; "
        "cli.build_parser('render').parse_args(['render', '--out', 'x', '--count', '1']); "
        "print(sorted(m for m in ('torch', 'onnx') if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_one_command_parses_as_the_whole_parser_does():
    argv = ["render", "--out", "x", "--count", "3", "--spp", "8", "--targets", "2"]
    assert vars(cli.build_parser("render").parse_args(argv)) == vars(
        cli.build_parser().parse_args(argv)
    )
