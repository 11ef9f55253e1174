"""The README's pictures are each redrawn by scripts/readme_pictures.sh, and the script's
commands are commands of `shaderball` with options they have (a renamed option fails here, not
when someone next redraws the pictures)."""

import re
import shlex
from pathlib import Path

from PIL import Image

from cli import main

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "scripts" / "readme_pictures.sh"


def readme_pictures() -> list[str]:
    text = (REPO / "README.md").read_text()
    section = text.split("\n## Pictures\n", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"!\[[^\]]*\]\(([^)]+)\)", section)


def script_commands() -> list[list[str]]:
    """The script's `"$SB" ...` commands, continuation lines joined, as argument lists."""
    text = SCRIPT.read_text().replace("\\\n", " ")
    return [shlex.split(line.strip())[1:] for line in text.splitlines() if line.strip().startswith('"$SB" ')]


def test_every_readme_picture_exists_and_the_script_draws_it():
    pictures = readme_pictures()
    assert len(pictures) >= 3, pictures
    script = SCRIPT.read_text()
    for path in pictures:
        assert (REPO / path).is_file(), f"README shows {path}, which does not exist"
        with Image.open(REPO / path) as image:
            assert image.format == "PNG" and min(image.size) >= 64, path
        assert re.search(rf"(--out|cp \S+) {re.escape(path)}\s*$", script, re.M), (
            f"README shows {path}, but scripts/readme_pictures.sh does not write it"
        )


def test_the_script_uses_commands_and_options_that_exist():
    commands = script_commands()
    assert {args[0] for args in commands} >= {"build", "preview", "train", "evaluate", "study"}
    for args in commands:
        command = main.commands.get(args[0])
        assert command is not None, f"scripts/readme_pictures.sh: no command {args[0]!r}"
        known = {opt for param in command.params for opt in (*param.opts, *param.secondary_opts)}
        used = [word for word in args[1:] if word.startswith("--")]
        unknown = [word for word in used if word not in known]
        assert not unknown, f"scripts/readme_pictures.sh: `shaderball {args[0]}` has no {', '.join(unknown)}"
