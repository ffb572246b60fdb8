"""The replay buffer's copy on the training device, sampled there: the GPU path's input pipeline.

The host `ReplayBuffer` stays the record (checkpoints, query negatives, the first epoch's negatives); this mirror
holds the same frame ring and transition arrays as torch tensors on the device and is brought up to date in one
batched copy before each block of updates (`sync`), not per env step. Sampling, the DrQ random shift and the
uint8 -> float conversion then run on the device with a fixed shape and no host value in them: the number of
stored transitions is a device scalar, so a sample can be captured in a CUDA graph and replayed as the buffer
grows.

The random shift is a clamped gather: replicate-padding an image by p and cropping at offset (dy, dx) equals
reading it at rows clamp(y + dy - p) and columns clamp(x + dx - p), so no padded copy is made.
"""

import numpy as np
import torch

from learner.replay import ReplayBuffer

SYNC_CHUNK = 65_536
"""Frames copied to the device per transfer (453 MB of pinned staging at 48 px, 1.4 GB at 84 px, at most)."""


class DeviceReplay:
    """A device mirror of `ReplayBuffer` (same slots and indices) with graph-safe sampling."""

    def __init__(self, replay: ReplayBuffer, device: torch.device) -> None:
        self.host = replay
        self.device = device
        self.frames = torch.zeros(replay.frames.shape, dtype=torch.uint8, device=device)
        self.obs_slot = torch.zeros(replay.capacity, dtype=torch.int64, device=device)
        self.next_slot = torch.zeros(replay.capacity, dtype=torch.int64, device=device)
        self.actions = torch.zeros(replay.actions.shape, dtype=torch.float32, device=device)
        self.not_done = torch.zeros(replay.capacity, dtype=torch.float32, device=device)
        self.env_reward = torch.zeros(replay.capacity, dtype=torch.float32, device=device)
        self.size = torch.zeros((), dtype=torch.float32, device=device)
        """len(host) as a device scalar: samples read it at replay time, so a captured sample sees the buffer grow."""
        self.last_index = torch.zeros((), dtype=torch.int64, device=device)
        self.person_index = torch.zeros(replay.capacity, dtype=torch.int64, device=device)
        """The host's person_indices() in their first person_count places."""
        self.person_count = torch.zeros((), dtype=torch.float32, device=device)
        self.frames_synced = 0
        self.added_synced = 0

    def sync(self) -> None:
        """Copy the frames and transitions added to the host buffer since the last sync (one batch each)."""
        host = self.host
        if host.frames_added == self.frames_synced and host.added == self.added_synced:
            return  # (a batch's updates after its first: no copy, no launch)
        first_frame = max(self.frames_synced, host.frames_added - host.frame_capacity)
        for start in range(first_frame, host.frames_added, SYNC_CHUNK):  # (a resumed run's whole ring: in chunks)
            slots = np.arange(start, min(start + SYNC_CHUNK, host.frames_added)) % host.frame_capacity
            self.frames[self._to_device(slots)] = self._to_device(host.frames[slots])
        first = max(self.added_synced, host.added - host.capacity)
        if first < host.added:
            index = np.arange(first, host.added) % host.capacity
            device_index = self._to_device(index)
            for name in ("obs_slot", "next_slot", "actions", "not_done"):
                getattr(self, name)[device_index] = self._to_device(getattr(host, name)[index])
            # the env's rewards read r_env(s'); a transition without it (an env that reports none) reads 0
            self.env_reward[device_index] = self._to_device(np.nan_to_num(host.env_reward[index], nan=0.0))
            person = host.person_indices()
            if len(person):
                self.person_index[: len(person)] = self._to_device(person)
            self.person_count.fill_(float(len(person)))
        self.frames_synced, self.added_synced = host.frames_added, host.added
        self.size.fill_(float(len(host)))
        self.last_index.fill_(max(len(host) - 1, 0))

    def _to_device(self, array: np.ndarray) -> torch.Tensor:
        """A host array on the device without waiting for it (pinned staging; the caching host allocator keeps
        the staging block until the copy has run)."""
        tensor = torch.from_numpy(np.ascontiguousarray(array))
        if self.device.type == "cuda":
            return tensor.pin_memory().to(self.device, non_blocking=True)
        return tensor.to(self.device)

    def sample_indices(self, count: int) -> torch.Tensor:
        """Uniform transition indices in [0, size), with replacement (no host read of size)."""
        uniform = torch.rand(count, device=self.device)
        return torch.minimum((uniform * self.size).long(), self.last_index)  # (u * size rounds up to size at times)

    def gather(self, slots: torch.Tensor, pad: int = 0) -> torch.Tensor:
        """uint8 NHWC frames at `slots`, each shifted by its own random offset in [-pad, pad] (DrQ) when pad > 0."""
        if pad <= 0:
            return self.frames[slots]
        count, height, width = slots.shape[0], self.frames.shape[1], self.frames.shape[2]
        offsets = torch.randint(-pad, pad + 1, (count, 2), device=self.device)
        rows = (torch.arange(height, device=self.device) + offsets[:, :1]).clamp_(0, height - 1)
        columns = (torch.arange(width, device=self.device) + offsets[:, 1:]).clamp_(0, width - 1)
        return self.frames[slots[:, None, None], rows[:, :, None], columns[:, None, :]]

    def sample(self, count: int, pad: int = 0, person_share: float = 0.0) -> dict[str, torch.Tensor]:
        """A SAC batch: indices, shifted uint8 obs and next_obs, the un-shifted next_obs (what f_psi rewards, as
        the host path's reward cache does), action, not_done, env_reward. As the host's: `person_share` of it from the
        transitions a person drove, once there are any (decided on the device, so a captured sample sees them)."""
        indices = self.sample_indices(count)
        person = round(person_share * count)
        if person:
            picks = (torch.rand(person, device=self.device) * self.person_count).long()
            picks = torch.minimum(picks, (self.person_count - 1).clamp(min=0).long())
            indices[:person] = torch.where(self.person_count > 0, self.person_index[picks], indices[:person])
        next_slots = self.next_slot[indices]
        return {
            "indices": indices,
            "obs": self.gather(self.obs_slot[indices], pad),
            "next_obs": self.gather(next_slots, pad),
            "next_obs_unshifted": self.frames[next_slots],
            "action": self.actions[indices],
            "not_done": self.not_done[indices],
            "env_reward": self.env_reward[indices],
        }

    def sample_next_frames(self, count: int) -> torch.Tensor:
        """Uniform replay observations (the s' of uniform transitions): VICE's negatives."""
        return self.frames[self.next_slot[self.sample_indices(count)]]
