"""Shared fixtures: seeding, one torch thread, small bonus models and batches.

The vector models match the mock envs of ``torchrl.testing.mocking_classes``
(7-dimensional observations, 7-dimensional or 7-way actions); the MiniGrid
models read hand-built batches of valid object/colour/state ids.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from torchrl_surprise import ICMModel, StateVAE
from torchrl_surprise.modules import VectorEncoder
from torchrl_surprise.modules.vae import (
    MINIGRID_NUM_COLORS,
    MINIGRID_NUM_OBJECTS,
    MINIGRID_NUM_STATES,
)

# What the recipes share (common) and the results tools (results) live in recipes/,
# outside the wheel; the recipes' scripts put it on sys.path the same way.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "recipes"))

#: Observation size of the vector mock envs (ContinuousActionVecMockEnv, ...).
OBS_DIM = 7
#: Action size (continuous) or number of actions (discrete) of the mock envs.
ACTION_DIM = 7
HIDDEN_DIM = 16
LATENT_DIM = 4


@pytest.fixture(autouse=True)
def _one_torch_thread():
    # The machine has two cores shared with other jobs: with two intra-op threads
    # the small models here run up to ten times slower than with one. Set per
    # test: closing a ParallelEnv raises the main process's thread count again.
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)


@pytest.fixture(autouse=True, scope="session")
def _paper_minigrid_ids():
    # Tests gymnasium.make the paper's MultiRoom ids directly; importing the
    # package registers nothing (tests/test_layout.py), so they are registered
    # here, as a user's script would (minigrid is a test dependency).
    from torchrl_surprise.envs import register_minigrid_envs

    register_minigrid_envs()


def random_minigrid_image(batch_shape=(), dtype=torch.uint8) -> torch.Tensor:
    """A ``[*batch, 7, 7, 3]`` grid of valid object, colour and state ids."""
    ids = [
        torch.randint(0, n, (*batch_shape, 7, 7))
        for n in (MINIGRID_NUM_OBJECTS, MINIGRID_NUM_COLORS, MINIGRID_NUM_STATES)
    ]
    return torch.stack(ids, -1).to(dtype)


def vector_transitions(
    batch_shape=(), *, action: str = "continuous", obs_dim: int = OBS_DIM
) -> TensorDict:
    """Transitions as a collector gives them: ``s_t``, ``a_t`` and ``next``."""
    batch_shape = tuple(batch_shape)
    if action == "continuous":
        act = torch.rand(*batch_shape, ACTION_DIM) * 2 - 1
    else:
        act = torch.randint(0, ACTION_DIM, batch_shape)
    return TensorDict(
        {
            "observation": torch.randn(*batch_shape, obs_dim),
            "action": act,
            "next": {
                "observation": torch.randn(*batch_shape, obs_dim),
                "reward": torch.randn(*batch_shape, 1),
            },
        },
        batch_shape,
    )


def minigrid_transitions(batch_shape=()) -> TensorDict:
    """MiniGrid-like transitions (``image`` + ``direction``, 7 discrete actions)."""
    batch_shape = tuple(batch_shape)
    return TensorDict(
        {
            "image": random_minigrid_image(batch_shape),
            "direction": torch.randint(0, 4, batch_shape),
            "action": torch.randint(0, 7, batch_shape),
            "next": {
                "image": random_minigrid_image(batch_shape),
                "direction": torch.randint(0, 4, batch_shape),
                "reward": torch.rand(*batch_shape, 1),
            },
        },
        batch_shape,
    )


@pytest.fixture
def make_vector_batch():
    """``make_vector_batch(batch_shape, action="continuous" | "discrete")``."""
    return vector_transitions


@pytest.fixture
def make_minigrid_batch():
    """``make_minigrid_batch(batch_shape)``: MiniGrid-like transitions."""
    return minigrid_transitions


@pytest.fixture
def make_minigrid_image():
    """``make_minigrid_image(batch_shape, dtype)``: a grid of valid ids."""
    return random_minigrid_image


@pytest.fixture
def vector_vae() -> StateVAE:
    return StateVAE.for_vector(OBS_DIM, latent_dim=LATENT_DIM, hidden_dim=HIDDEN_DIM)


@pytest.fixture
def minigrid_vae() -> StateVAE:
    return StateVAE.for_minigrid(latent_dim=LATENT_DIM, hidden_dim=HIDDEN_DIM)


@pytest.fixture
def continuous_icm() -> ICMModel:
    return ICMModel.for_vector(OBS_DIM, ACTION_DIM, hidden_dim=HIDDEN_DIM)


@pytest.fixture
def discrete_icm() -> ICMModel:
    return ICMModel(
        VectorEncoder(OBS_DIM, hidden_dim=HIDDEN_DIM),
        ACTION_DIM,
        discrete=True,
        hidden_dim=HIDDEN_DIM,
    )


@pytest.fixture
def minigrid_icm() -> ICMModel:
    return ICMModel.for_minigrid(num_actions=7, hidden_dim=HIDDEN_DIM)
