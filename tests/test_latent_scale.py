"""The elliptical bonus's scale on a real MiniGrid env, from a run's checkpoint."""

from __future__ import annotations

import pandas as pd
import pytest
import torch
from _recipe_run import run_results_script

from results.latent_scale import main
from torchrl_surprise import StateVAE
from torchrl_surprise.transforms import VAEEllipticalTransform, VAESurpriseTransform


def _run(run_dir, variant: str, loc_scale: float = 1.0) -> None:
    """A run directory holding a checkpoint of a DoorKey-5x5 VAE bonus, its
    posterior means scaled by ``loc_scale``."""
    torch.manual_seed(0)
    vae = StateVAE.for_minigrid(latent_dim=4, hidden_dim=16)
    with torch.no_grad():
        vae.head.weight[:4] *= loc_scale
        vae.head.bias[:4] *= loc_scale
    cls = VAEEllipticalTransform if variant == "elliptical" else VAESurpriseTransform
    config = {
        "bonus": "vae",
        "seed": 3,
        "setting": f"{variant}_{loc_scale:g}",
        "env": {"name": "MiniGrid-DoorKey-5x5-v0", "backend": "gymnasium"},
        "intrinsic": {
            "normalization": "none",
            "vae": {
                "variant": variant,
                "latent_dim": 4,
                "hidden_dim": 16,
                "use_direction": True,
                "ridge": 0.1,
            },
        },
    }
    run_dir.mkdir()
    torch.save(
        {"config": config, "frames": 256, "bonus_transform": cls(vae).state_dict()},
        run_dir / "checkpoint.pt",
    )


def test_longer_posterior_means_change_the_raw_bonus_not_the_unit_one(tmp_path):
    _run(tmp_path / "short", "elliptical")
    _run(tmp_path / "long", "elliptical", loc_scale=3.0)
    out = tmp_path / "scale.csv"
    argv = [str(tmp_path / "short"), str(tmp_path / "long"), "--out", str(out)]
    assert main([*argv, "--envs", "2", "--steps", "40"]) == 0
    table = pd.read_csv(out).set_index("setting")
    short, long = table.loc["elliptical_1"], table.loc["elliptical_3"]
    assert (short["seed"], short["frames"]) == (3, 256)
    assert (short["global_bonus"], bool(short["unit_latent"])) == ("none", False)
    assert long["mean_sq_norm"] == pytest.approx(9 * short["mean_sq_norm"], rel=1e-3)
    # an episode's first state: |mu|^2 / ridge; at unit length 1 / ridge
    assert long["first"] == pytest.approx(9 * short["first"], rel=1e-3)
    assert short["unit_first"] == long["unit_first"] == pytest.approx(10.0)
    for column in ("unit_other_mean", "unit_other_p99", "unit_tail"):
        assert short[column] == pytest.approx(long[column], rel=1e-3)
    assert long["other_mean"] > short["other_mean"]


def test_a_committed_table_plus_a_new_run_is_the_table_of_both_at_once(tmp_path):
    # --from-data: a run no longer on disk keeps its committed row, in its place
    _run(tmp_path / "short", "elliptical")
    _run(tmp_path / "long", "elliptical", loc_scale=3.0)
    short, long = str(tmp_path / "short"), str(tmp_path / "long")
    common = ["--envs", "2", "--steps", "20", "--out"]
    whole, part = tmp_path / "whole.csv", tmp_path / "part.csv"
    assert main([short, long, *common, str(whole)]) == 0
    assert main([short, *common, str(part)]) == 0
    for _ in range(2):  # in place, and again
        assert main([long, "--from-data", str(part), *common, str(part)]) == 0
        assert part.read_bytes() == whole.read_bytes()
    # given again, the first run keeps its place
    assert main([short, "--from-data", str(part), *common, str(part)]) == 0
    assert part.read_bytes() == whole.read_bytes()


def test_a_run_without_the_elliptical_bonus_is_named(tmp_path, capsys):
    _run(tmp_path / "kl", "kl")
    with pytest.raises(SystemExit) as raised:
        main([str(tmp_path / "kl"), "--envs", "2", "--steps", "5"])
    assert raised.value.code == 2
    assert "variant is 'kl'; the latent's scale is measured for the elliptical" in (
        capsys.readouterr().err
    )


def test_the_documented_command_runs_as_a_script(tmp_path):
    # as docs/results.rst runs it: a script, with nothing of recipes/ importable
    # but what it puts on sys.path itself
    _run(tmp_path / "run", "elliptical")
    run_results_script(
        "latent_scale.py",
        str(tmp_path / "run"),
        *("--envs", "2", "--steps", "20", "--out", str(tmp_path / "scale.csv")),
        cwd=tmp_path,
    )
    assert pd.read_csv(tmp_path / "scale.csv")["setting"].tolist() == ["elliptical_1"]
