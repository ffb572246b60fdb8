"""Replay buffer of image transitions that stores each frame once, plus DrQ's random shift done as a gather.

A transition (s, a, s', d, r_env(s')) points at two frame slots; s' of one step is s of the next, so a frame
is stored once (about 1 + 1/T frames per transition for episodes of length T). Each transition adds at most
two frames (its s' and, after a reset, its s), and with `envs` envs in lockstep an env's s was stored at most
2 (envs - 1) frames before its transition, so a frame ring of 2 capacity + 2 envs never overwrites a frame a
live transition uses. np.zeros is lazily committed, so the unused part costs no memory.
"""

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from numpy.lib.stride_tricks import as_strided


@dataclass
class Batch:
    """uint8 NHWC images (augmented when asked) and the rest as float32 arrays."""

    indices: np.ndarray
    obs: np.ndarray
    action: np.ndarray
    next_obs: np.ndarray
    not_done: np.ndarray


def edge_pad(images: np.ndarray, pad: int) -> np.ndarray:
    """np.pad(mode="edge") on the two spatial axes of NHWC images, in five vectorised copies (np.pad is slower)."""
    count, height, width, channels = images.shape
    out = np.empty((count, height + 2 * pad, width + 2 * pad, channels), dtype=images.dtype)
    out[:, pad:-pad, pad:-pad] = images
    out[:, :pad, pad:-pad] = images[:, :1]
    out[:, -pad:, pad:-pad] = images[:, -1:]
    out[:, :, :pad] = out[:, :, pad : pad + 1]
    out[:, :, -pad:] = out[:, :, -pad - 1 : -pad]
    return out


def random_shift(images: np.ndarray, pad: int, rng: np.random.Generator) -> np.ndarray:
    """DrQ random shift: replicate-pad by `pad` and crop back at a random offset, per image, on uint8 NHWC.

    The crops are one gather from a (count, offset_y, offset_x, H, W, C) strided view of the padded batch, so
    no Python loop over images or offsets.
    """
    if pad <= 0:
        return images
    count, height, width, channels = images.shape
    padded = edge_pad(images, pad)
    offsets = rng.integers(0, 2 * pad + 1, size=(count, 2))
    batch_stride, row_stride, column_stride, channel_stride = padded.strides
    crops = as_strided(
        padded, (count, 2 * pad + 1, 2 * pad + 1, height, width, channels),
        (batch_stride, row_stride, column_stride, row_stride, column_stride, channel_stride), writeable=False,
    )  # fmt: skip
    return crops[np.arange(count), offsets[:, 0], offsets[:, 1]]


def shift_pad(image_size: int) -> int:
    """DrQ shifts 84 px images by up to 4 px; the same fraction of the image, at least 1 px."""
    return max(1, round(4 * image_size / 84))


class ReplayBuffer:
    """Transitions in a ring of `capacity`; frames in a ring of 2 * capacity + 2 * envs."""

    def __init__(self, capacity: int, image_shape: tuple[int, int, int], action_dim: int, envs: int = 1) -> None:
        self.capacity = capacity
        self.frame_capacity = 2 * capacity + 2 * envs
        self.frames = np.zeros((self.frame_capacity, *image_shape), dtype=np.uint8)
        self.obs_slot = np.zeros(capacity, dtype=np.int64)
        self.next_slot = np.zeros(capacity, dtype=np.int64)
        self.actions = np.zeros((capacity, action_dim), dtype=np.float32)
        self.not_done = np.zeros(capacity, dtype=np.float32)
        # the env's figure for s' (the method's `env_reward`: success(s'), or minus the hand's distance; nan: none)
        self.env_reward = np.full(capacity, np.nan, dtype=np.float32)
        self.person = np.zeros(capacity, dtype=bool)  # a person drove the step by hand (a take-over)
        self._person_indices: tuple[int, np.ndarray] = (0, np.zeros(0, dtype=np.int64))  # (added, indices) cache
        # f_psi(s') per transition and the classifier version that computed it (-1: none)
        self.reward_cache = np.zeros(capacity, dtype=np.float32)
        self.reward_version = np.full(capacity, -1, dtype=np.int64)
        self.frames_added = 0
        self.added = 0

    def __len__(self) -> int:
        return min(self.added, self.capacity)

    def add_frame(self, image: np.ndarray) -> int:
        """Store one uint8 HWC observation; returns its slot."""
        slot = self.frames_added % self.frame_capacity
        self.frames[slot] = image
        self.frames_added += 1
        return slot

    def add(
        self, obs_slot: int, action: np.ndarray, next_slot: int, terminated: bool, env_reward: float | None,
        person: bool = False,
    ) -> int:  # fmt: skip
        """Store a transition between two stored frames (`person`: a person drove it by hand); returns its index."""
        index = self.added % self.capacity
        self.obs_slot[index] = obs_slot
        self.next_slot[index] = next_slot
        self.actions[index] = action
        self.not_done[index] = 0.0 if terminated else 1.0
        self.env_reward[index] = np.nan if env_reward is None else env_reward
        self.person[index] = person
        self.reward_version[index] = -1
        self.added += 1
        return index

    def person_indices(self) -> np.ndarray:
        """The indices of the stored transitions a person drove by hand."""
        added, indices = self._person_indices
        if added != self.added:
            indices = np.flatnonzero(self.person[: len(self)])
            self._person_indices = (self.added, indices)
        return indices

    def sample(self, rng: np.random.Generator, batch_size: int, pad: int = 0, person_share: float = 0.0) -> Batch:
        """Uniform with replacement, except that `person_share` of the batch (once there are any) comes from the
        transitions a person drove (HIL-SERL's demo buffer); s and s' shifted independently when pad > 0 (DrQ)."""
        indices = rng.integers(0, len(self), size=batch_size)
        person = self.person_indices() if person_share > 0 else ()
        if len(person):
            count = round(person_share * batch_size)
            indices[:count] = person[rng.integers(0, len(person), size=count)]
        obs = self.frames[self.obs_slot[indices]]
        next_obs = self.frames[self.next_slot[indices]]
        if pad > 0:
            obs, next_obs = random_shift(obs, pad, rng), random_shift(next_obs, pad, rng)
        return Batch(indices, obs, self.actions[indices], next_obs, self.not_done[indices])

    def sample_next_frames(self, rng: np.random.Generator, count: int) -> np.ndarray:
        """Uniform replay observations (the s' of uniform transitions): VICE's negatives."""
        indices = rng.integers(0, len(self), size=count)
        return self.frames[self.next_slot[indices]]

    def frames_since(self, first_frame: int) -> np.ndarray:
        """All frames added since the absolute frame number `first_frame` (still in the ring); a negative
        `first_frame` (fewer frames than asked for) means from the first frame."""
        first = max(first_frame, 0, self.frames_added - self.frame_capacity)
        slots = np.arange(first, self.frames_added) % self.frame_capacity
        return self.frames[slots]

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        used = len(self)
        frames = min(self.frames_added, self.frame_capacity)
        return {
            "capacity": self.capacity,
            "frame_capacity": self.frame_capacity,
            "frames": torch.from_numpy(self.frames[:frames]),
            "obs_slot": torch.from_numpy(self.obs_slot[:used]),
            "next_slot": torch.from_numpy(self.next_slot[:used]),
            "actions": torch.from_numpy(self.actions[:used]),
            "not_done": torch.from_numpy(self.not_done[:used]),
            "env_reward": torch.from_numpy(self.env_reward[:used]),
            "person": torch.from_numpy(self.person[:used]),
            "frames_added": self.frames_added,
            "added": self.added,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        if state["capacity"] != self.capacity:
            raise ValueError(f"checkpoint replay capacity {state['capacity']} != {self.capacity}")
        saved_ring = int(state.get("frame_capacity", 2 * self.capacity + 2))  # (before num_envs: one env's ring)
        if saved_ring != self.frame_capacity:  # frame slots are positions in the saved ring
            raise ValueError(
                f"checkpoint frame ring of {saved_ring} frames != {self.frame_capacity}: the run's num_envs changed"
            )
        frames = state["frames"].numpy()
        self.frames[: len(frames)] = frames
        used = len(state["obs_slot"])
        for name in ("obs_slot", "next_slot", "actions", "not_done"):
            getattr(self, name)[:used] = state[name].numpy()
        self.env_reward[:used] = state.get("env_reward", state.get("success")).numpy()  # (before: only success)
        if "person" in state:  # (checkpoints written before take-overs have none)
            self.person[:used] = state["person"].numpy()
        self.frames_added, self.added = int(state["frames_added"]), int(state["added"])
        self.reward_version[:] = -1
