"""The recipes behind the model card's measurements are shell scripts: each must parse and
say how it is run, so that a lost data folder can be rebuilt from them."""

import subprocess
from pathlib import Path

RECIPES = Path(__file__).resolve().parents[1] / "recipes"


def test_every_recipe_parses_and_says_how_to_run_it():
    scripts = sorted(p for p in RECIPES.iterdir() if p.is_file())
    assert {p.name for p in scripts} >= {"rebuild-data", "teach-k1", "score-heldout"}
    for script in scripts:
        subprocess.run(["bash", "-n", str(script)], check=True)
        text = script.read_text()
        assert f"models/train/recipes/{script.name}" in text, f"{script.name}: no usage line"
        assert script.stat().st_mode & 0o111, f"{script.name} is not executable"


def _launcher(tmp_path: Path, status: int = 0) -> Path:
    """A recipe that starts background jobs, as render-families does, reduced to
    reporting where it ran: pid, session, nice, arguments, then its autogroup."""
    script = tmp_path / "launcher"
    script.write_text(
        "#!/usr/bin/env bash\nset -euo pipefail\n"
        f'LOWEST_PRIORITY_LAUNCHER=1 source "{RECIPES}/lowest-priority"\n'
        'echo "$$ $(ps -o sid= -p $$ | tr -d " ") $(ps -o ni= -p $$ | tr -d " ")'
        ' $(printf "[%s]" "$@")"\n'
        "cat /proc/self/autogroup 2>/dev/null || true\n"
        f"exit {status}\n"
    )
    script.chmod(0o755)
    return script


def test_a_launcher_started_inside_another_session_leads_its_own_at_nice_19(tmp_path):
    # Started as a child of this test (not a session leader), as from a terminal.
    done = subprocess.run(
        [str(_launcher(tmp_path)), "a", "b c"], capture_output=True, text=True, check=True
    )
    first, *rest = done.stdout.splitlines()
    pid, sid, nice, args = first.split(" ", 3)
    assert pid == sid, "the launcher did not become the leader of a new session"
    assert nice == "19"
    assert args == "[a][b c]", "the arguments did not reach the second start as given"
    if rest:  # the kernel groups sessions (autogroup): the new group is lowered too
        assert rest[0].endswith("nice 19"), rest[0]


def test_a_launcher_keeps_its_exit_status_and_one_that_leads_runs_once(tmp_path):
    failed = subprocess.run([str(_launcher(tmp_path, status=3))], capture_output=True)
    assert failed.returncode == 3
    # Already a session leader: no second start (the same process reports).
    with subprocess.Popen(
        [str(_launcher(tmp_path))], stdout=subprocess.PIPE, text=True, start_new_session=True
    ) as led:
        out, _ = led.communicate()
    pid, sid, nice = out.split()[:3]
    assert pid == sid == str(led.pid)
    assert nice == "19"
