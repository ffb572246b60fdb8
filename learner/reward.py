"""The reward classifier f_psi and its training for each method (original-implementation.md, the per-method table).

vice / vice_raq: AIRL discriminator D(s, a) = sigmoid(f_psi(s) - log pi(a|s)) (the paper's Eq. for D), a fresh
    a ~ pi(.|s) for every positive (Alg. 2 line 10) and every negative; negatives are uniform replay samples.
raq / naive_classifier: plain sigmoid cross-entropy on f_psi(s).
Mixup (Eq. mixup): lambda ~ Beta(alpha, alpha) per sample, each sample mixed with a random permutation of the
combined batch, images and labels alike.
The SAC reward is the logit f_psi(s') itself (no log pi, no normalisation). f_psi runs under the run's
precision like the SAC networks (bf16 autocast: convs and hidden layers in bf16; weights, the last layer and the
loss in fp32, so logits, rewards and query scores are not rounded to bf16).
"""

import copy
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F

from contract.algorithms import ALGORITHM_SPECS
from contract.config import ClassifierConfig, NetworkConfig, TrainConfig
from contract.images import decoded_array, model_array
from contract.store import Store
from learner.networks import RewardClassifier, autocast_of, dtype_of, resolve_precision, to_float
from learner.replay import ReplayBuffer

Policy = Callable[[torch.Tensor], tuple[torch.Tensor, torch.Tensor]]
"""float images -> (a ~ pi(.|s), log pi(a|s)), without gradients."""


def mixup(
    images: torch.Tensor, labels: torch.Tensor, alpha: float, rng: np.random.Generator | None
) -> tuple[torch.Tensor, torch.Tensor]:
    """x~ = lam x_i + (1 - lam) x_perm(i), y~ likewise, lam ~ Beta(alpha, alpha) per sample. Drawn from `rng`, or
    with rng=None from torch's generator on the images' device (no host values: a CUDA graph can hold it)."""
    if alpha <= 0:
        return images, labels
    count, device = images.shape[0], images.device
    if rng is not None:
        lam = torch.from_numpy(rng.beta(alpha, alpha, size=count).astype(np.float32)).to(device)
        perm = torch.from_numpy(rng.permutation(count)).to(device)
    else:  # Beta(a, a) as G1 / (G1 + G2), G ~ Gamma(a, 1); a permutation as the order of uniform keys
        gammas = torch._standard_gamma(torch.full((2, count), float(alpha), device=device))
        lam = gammas[0] / gammas.sum(0)
        perm = torch.argsort(torch.rand(count, device=device))
    lam = lam.to(images.dtype)  # bf16 images: the labels mix with the same (rounded) lambda
    # Gathered and mixed in memory order: to_float's images are channels_last (NHWC in memory), where indexing
    # the NCHW view took twice as long on a CPU (3.4 vs 1.6 ms for 256 48x48 images).
    channels_last = images.dim() == 4 and images.is_contiguous(memory_format=torch.channels_last)
    rows = images.permute(0, 2, 3, 1) if channels_last else images
    mixed = torch.lerp(rows.index_select(0, perm), rows, lam.view(-1, *([1] * (rows.dim() - 1))))
    mixed_images = mixed.permute(0, 3, 1, 2) if channels_last else mixed
    mixed_labels = torch.lerp(labels[perm], labels, lam.to(labels.dtype))
    return mixed_images, mixed_labels


class RewardModel:
    """f_psi with its optimizer, its positive and negative example sets and a version counter.

    Two copies of f_psi: `trainee`, which the classifier steps train (Adam's parameters), and `net`, the live one
    that rewards and query scores read; `publish` copies the trainee into the live net and increases the version,
    so a reward cached with the version that computed it is exact until the next publish. A step publishes at once
    unless told not to: an epoch trained on the update thread beside an evaluation publishes when its last step
    is done, so the evaluation's record reads one f_psi.
    """

    def __init__(
        self, classifier: ClassifierConfig, networks: NetworkConfig, rng: np.random.Generator, *, airl: bool,
        image_size: int, device: str = "cpu", precision: str = "auto",
    ) -> None:  # fmt: skip
        """`airl`: trained as VICE's discriminator (AlgorithmSpec.airl), else as a plain classifier."""
        self.config = classifier
        self.rng = rng
        self.device = torch.device(device)
        self.precision = resolve_precision(precision, self.device.type)
        self.net = RewardClassifier(image_size, networks.conv_filters, networks.hidden_dim, networks.encoder)
        self.net.to(self.device, memory_format=torch.channels_last)
        self.trainee = copy.deepcopy(self.net)
        self.opt = torch.optim.Adam(
            self.trainee.parameters(), lr=classifier.classifier_lr, capturable=self.device.type == "cuda"
        )  # (capturable: its step counts on the device, so a step can be a CUDA graph)
        self.airl = airl
        shape = (0, image_size, image_size, 3)
        self.goals = np.zeros(shape, dtype=np.uint8)
        self.answered_positives = np.zeros(shape, dtype=np.uint8)
        self.initial_negatives = np.zeros(shape, dtype=np.uint8)
        self.answered_negatives = np.zeros(shape, dtype=np.uint8)
        self.version = 0

    @classmethod
    def for_run(cls, config: TrainConfig, rng: np.random.Generator) -> "RewardModel":
        """The run's f_psi: its classifier and network parts, its method's loss, its image size and device."""
        return cls(
            config.classifier, config.networks, rng, airl=ALGORITHM_SPECS[config.algorithm].airl,
            image_size=config.image_size, device=config.device, precision=config.precision,
        )  # fmt: skip

    # ------------------------------------------------------------------ example sets
    @property
    def positives(self) -> np.ndarray:
        return np.concatenate([self.goals, self.answered_positives])

    @property
    def negatives(self) -> np.ndarray:
        return np.concatenate([self.initial_negatives, self.answered_negatives])

    def add_positive(self, image: np.ndarray) -> None:
        self.answered_positives = np.concatenate([self.answered_positives, image[None]])

    def add_negative(self, image: np.ndarray) -> None:
        self.answered_negatives = np.concatenate([self.answered_negatives, image[None]])

    # ------------------------------------------------------------------ inference
    def autocast(self) -> AbstractContextManager[Any]:
        return autocast_of(self.precision, self.device)

    def images(self, images: np.ndarray) -> torch.Tensor:
        """uint8 NHWC -> f_psi's input (bf16 at once under bf16 precision)."""
        return to_float(images, self.device, dtype_of(self.precision))

    @torch.no_grad()
    def logits(self, images: np.ndarray, chunk: int = 1024) -> np.ndarray:
        """f_psi for uint8 NHWC images (fp32 logits), in chunks."""
        with self.autocast():
            out = [self.net(self.images(images[i : i + chunk])) for i in range(0, len(images), chunk)]
        return torch.cat(out).cpu().numpy() if out else np.zeros(0, dtype=np.float32)

    def rewards_on_device(self, images: torch.Tensor) -> torch.Tensor:
        """r = f_psi(s') of uint8 NHWC device images, without a host sync (as `rewards` computes it)."""
        return self.logits_on_device(images).float()

    def logits_on_device(self, images: torch.Tensor) -> torch.Tensor:
        """f_psi (fp32 logits) of uint8 NHWC images already on the device, without gradients or a host sync."""
        with torch.no_grad(), self.autocast():
            return self.net(self.images(images))

    def rewards(self, replay: ReplayBuffer, indices: np.ndarray) -> np.ndarray:
        """r = f_psi(s') for replay transitions, with the current classifier (cached per version, exact)."""
        stale = indices[replay.reward_version[indices] != self.version]
        if len(stale):
            stale = np.unique(stale)
            replay.reward_cache[stale] = self.logits(replay.frames[replay.next_slot[stale]])
            replay.reward_version[stale] = self.version
        return replay.reward_cache[indices]

    # ------------------------------------------------------------------ training
    def sample_positives(self, count: int, rng: np.random.Generator | None = None) -> np.ndarray:
        positives = self.positives
        return positives[(rng or self.rng).integers(0, len(positives), size=count)]

    def sample_negatives(self, count: int, rng: np.random.Generator | None = None) -> np.ndarray:
        negatives = self.negatives
        return negatives[(rng or self.rng).integers(0, len(negatives), size=count)]

    def discriminator_logits(
        self, images: torch.Tensor, policy: Policy | None
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """(logit of D, f_psi, log pi or None) of the trainee. AIRL form: logit D(s, a) = f_psi(s) - log pi(a|s),
        a ~ pi(.|s)."""
        f = self.trainee(images)
        if not self.airl or policy is None:
            return f, f, None
        _, log_pi = policy(images)  # a fresh action for every sample; pi is not trained by this loss
        log_pi = log_pi.detach().float()
        return f - log_pi, f, log_pi

    def update_classifier(
        self, positives: np.ndarray, negatives: np.ndarray, policy: Policy | None = None, *, accuracy: bool = True,
        rng: np.random.Generator | None = None, publish: bool = True,
    ) -> dict[str, float]:  # fmt: skip
        """One Adam step of the method's loss on uint8 NHWC positives and negatives, mixup drawn from `rng` (default
        the run's); returns metrics (the accuracies need another forward pass of f_psi and pi: `accuracy=False`
        leaves them out). `publish=False` leaves the live f_psi as it was.

        Mixup with the AIRL form: the discriminator is a function of (s, a), so the mixed sample must be one
        (s~, a~) pair; we sample a~ ~ pi(.|s~) for the mixed image and use f_psi(s~) - log pi(a~|s~) as its
        logit, against the mixed label. (Mixing the log pi terms of the two sources instead would not be the
        discriminator of Eq. D at any input.) Without mixup this is exactly Alg. 2 lines 9-12.
        """
        images = self.images(np.concatenate([positives, negatives]))
        loss = self._step(images, len(positives), policy, rng or self.rng)
        metrics = {"reward/loss": loss.item()}
        if accuracy:
            metrics.update(self._accuracy(images, len(positives), policy))
        if publish:
            self.publish()
        return metrics

    @torch.no_grad()
    def publish(self) -> None:
        """The trainee's weights into the live f_psi (in place: a captured graph keeps reading them); a new
        version, so every cached reward is stale."""
        torch._foreach_copy_(list(self.net.parameters()), list(self.trainee.parameters()))
        self.version += 1

    def step_on_device(self, positives: torch.Tensor, negatives: torch.Tensor, policy: Policy | None) -> torch.Tensor:
        """`update_classifier` on uint8 NHWC device tensors, mixup drawn on the device: no host sync, so a CUDA
        graph can hold it (the graph's replays do not run Python: the caller publishes it). Returns the loss."""
        return self._step(self.images(torch.cat([positives, negatives])), len(positives), policy, None)

    def _step(
        self, images: torch.Tensor, n_positive: int, policy: Policy | None, rng: np.random.Generator | None
    ) -> torch.Tensor:
        labels = torch.zeros(len(images), device=self.device)
        labels[:n_positive] = 1.0
        mixed_images, mixed_labels = mixup(images, labels, self.config.mixup_alpha, rng)
        with self.autocast():
            logits, _, _ = self.discriminator_logits(mixed_images, policy)
        loss = F.binary_cross_entropy_with_logits(logits, mixed_labels)
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        self.opt.step()
        return loss.detach()

    @torch.no_grad()
    def _accuracy(self, images: torch.Tensor, n_positive: int, policy: Policy | None) -> dict[str, float]:
        """The discriminator's accuracy on the unmixed batch, and mean f_psi per class."""
        with self.autocast():
            logits, f, log_pi = self.discriminator_logits(images, policy)
        metrics = {
            "reward/acc_goal": (logits[:n_positive] > 0).float().mean().item(),
            "reward/acc_replay": (logits[n_positive:] < 0).float().mean().item(),
            "reward/mean_logit_goal": f[:n_positive].mean().item(),
            "reward/mean_logit_replay": f[n_positive:].mean().item(),
        }
        if log_pi is not None:
            metrics["reward/mean_log_pi"] = log_pi.mean().item()
        return metrics

    # ------------------------------------------------------------------ state
    def state_dict(self) -> dict[str, Any]:
        """(Taken with the trainee published: the live f_psi is the same.)"""
        return {
            "net": self.trainee.state_dict(),
            "opt": self.opt.state_dict(),
            "version": self.version,
            "goals": torch.from_numpy(self.goals.copy()),
            "answered_positives": torch.from_numpy(self.answered_positives.copy()),
            "initial_negatives": torch.from_numpy(self.initial_negatives.copy()),
            "answered_negatives": torch.from_numpy(self.answered_negatives.copy()),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.net.load_state_dict(state["net"])
        self.trainee.load_state_dict(state["net"])
        self.opt.load_state_dict(state["opt"])
        self.version = int(state["version"]) + 1  # anything cached before the load is stale
        for name in ("goals", "answered_positives", "initial_negatives", "answered_negatives"):
            setattr(self, name, state[name].numpy())


def goal_examples(store: Store, goal_set_id: int, size: int) -> tuple[np.ndarray, str]:
    """A goal set's examples at `size` x `size` px (remade from their originals where the set's model size is
    another), and what the run's events say of them."""
    goals = store.goal_images(goal_set_id=goal_set_id)
    if not goals:
        raise ValueError(f"goal set {goal_set_id} has no goal examples")
    images, remade = [], 0
    for goal in goals:
        image = decoded_array(goal.model_png)
        if image.shape[:2] != (size, size):
            image = model_array(goal.original, size)
            remade += 1
        images.append(image)
    note = f" ({remade} remade at {size}x{size} px from their originals)" if remade else ""
    return np.stack(images), f"loaded {len(goals)} goal examples{note}"
