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
