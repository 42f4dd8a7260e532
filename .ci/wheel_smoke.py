"""The installed wheel, used from outside the repository: one REINFORCE + SDE estimate on the
function-minimisation task, the ball-catching env registered with gymnasium, the config tree shipped
without the study's, and two jobs trained from a directory of their own: ``python -m sde_torchrl
+experiment=minimize`` and a 2-update ball-catching job through the ``sde-train`` command."""

from __future__ import annotations

import importlib.metadata
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import gymnasium
import torch

import sde_torchrl
from sde_torchrl import LinearActor, ReinforceEstimator, SDEParams, make_minimize_env, make_sde_actor
from sde_torchrl.collectors.rollout import collect_episodes

assert "site-packages" in Path(sde_torchrl.__file__).parts, sde_torchrl.__file__
torch.manual_seed(0)
sde = SDEParams(1, 1)
policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
env = make_minimize_env(15, episodes=10).append_transform(sde.make_tensordict_primer())
loss = ReinforceEstimator(policy)(collect_episodes(env, policy, 15))
assert torch.isfinite(loss["loss_objective"]), loss
assert "sde_torchrl/BallCatch-v0" in gymnasium.envs.registry

# the library's config tree ships in the package; the study's (analysis/conf/, its search-path plugin) does not
conf = Path(sde_torchrl.__file__).parent / "conf"
assert (conf / "config.yaml").is_file() and (conf / "hydra" / "launcher" / "slurm.yaml").is_file(), conf
experiments = {path.stem for path in (conf / "experiment").glob("*.yaml")}
assert {"minimize", "ballcatch", "ppo_halfcheetah_bullet"} <= experiments, experiments
assert not list(conf.rglob("*_sweep.yaml")), sorted(conf.rglob("*_sweep.yaml"))
try:
    study_plugin = importlib.util.find_spec("hydra_plugins.sde_torchrl_study")
except ModuleNotFoundError:  # no Hydra plugin installed at all
    study_plugin = None
assert study_plugin is None, study_plugin


def train(command: list[str], *overrides: str) -> dict:
    """Runs ``command overrides hydra.run.dir=...`` in an empty directory outside the clone: exit 0 and
    a summary.json, returned."""
    with tempfile.TemporaryDirectory(prefix="sde_torchrl_wheel_") as directory:
        run_dir = Path(directory) / "run"
        environment = {key: value for key, value in os.environ.items() if key != "PYTHONPATH"}
        result = subprocess.run([*command, *overrides, f"hydra.run.dir={run_dir}"], cwd=directory, env=environment,
                                capture_output=True, text=True, timeout=600)
        assert result.returncode == 0, (command, overrides, result.returncode, result.stderr[-3000:])
        return json.loads((run_dir / "summary.json").read_text())


minimize = train([sys.executable, "-m", "sde_torchrl"], "+experiment=minimize")
assert minimize["updates_done"] == 300, minimize
sde_train = Path(sys.executable).parent / "sde-train"
ballcatch = train([str(sde_train)], "+experiment=ballcatch", "updates=2", "runs=1", "final_episodes=0",
                  "episode_queue=13", "eval_period=1", "eval_episodes=1", "env.episode_length=100", "logger=none")
assert ballcatch["updates_done"] == 2, ballcatch
print(f"sde_torchrl {importlib.metadata.version('sde_torchrl')} from {Path(sde_torchrl.__file__).parent}: ok "
      "(python -m sde_torchrl +experiment=minimize, sde-train +experiment=ballcatch for 2 updates)")
