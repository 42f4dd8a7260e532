"""``python train.py --help``: what a user chooses (the groups and their options, as ``conf/``
holds them, without the internal schemas) and every top-level setting explained."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest
from _helpers import REPO

from sde_torchrl.config.help import GROUPS, option_names, setting_lines
from sde_torchrl.config.schemas.train import TrainConf

# every test reads one `train.py --help` process's output (the module fixture): on one xdist worker, it runs once
pytestmark = pytest.mark.xdist_group("help_output")


@pytest.fixture(scope="module")
def help_output() -> str:
    done = subprocess.run([sys.executable, "train.py", "+experiment=ballcatch", "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_help_lists_every_group_a_user_chooses_with_its_options_and_no_schema(help_output):
    groups = sorted(path.name for path in (REPO / "conf").iterdir() if path.is_dir() and path.name != "hydra")
    assert sorted(GROUPS) == groups
    words = help_output.replace(",", " ").split()
    for group in groups:
        assert f"{group}:" in words
        assert set(option_names(REPO / "conf", group)) <= set(words), group
    assert "schema" not in help_output


def test_help_explains_every_setting_with_its_default(help_output):
    fields = {field.name: field.default for field in dataclasses.fields(TrainConf) if field.name not in GROUPS}
    explained = dict(setting_lines())
    assert sorted(explained) == sorted(fields)
    for name, line in explained.items():
        assert line in help_output
        assert len(line.split(": ", 1)[1]) > 10, f"{name} is not explained"
    assert "  runs=1: independent learners" in help_output


def test_help_ends_with_the_composed_config_of_the_choices(help_output):
    config = help_output.split("== The config these choices compose ==", 1)[1]
    assert "episode_queue: 20" in config and "$CONFIG" not in config  # +experiment=ballcatch's queue
