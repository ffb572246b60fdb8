"""The paper's networks (Fig. 2): conv encoder, tanh-Gaussian actor, twin Q critic and reward classifier f_psi.

Images enter as uint8 NHWC (how envs and the replay buffer hold them) and are turned into float NCHW tensors
with channels_last strides once per batch (`to_float`), which is the layout the CPU conv kernels prefer.
"""

import functools
import math
import time
from contextlib import AbstractContextManager
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0
"""Clamp of the actor's log standard deviation (softlearning's bounds)."""

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)
_LOG_2 = math.log(2.0)


def to_float(
    images: np.ndarray | torch.Tensor, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """uint8 (B, H, W, 3) -> float (B, 3, H, W) in [0, 1], channels_last in memory (a permute, no copy).

    dtype=bfloat16 gives what autocast would hand the first conv (each value x / 255 rounded once to bf16),
    without the float32 tensor in between."""
    tensor = torch.from_numpy(np.ascontiguousarray(images)) if isinstance(images, np.ndarray) else images
    tensor = tensor.to(device, non_blocking=True).permute(0, 3, 1, 2)
    return tensor.to(dtype).div_(255.0)


PRECISIONS = ("auto", "fp32", "bf16")
# "auto" picks bf16 on a CPU only when its bf16 matmuls beat fp32 by this factor: CPUs without native bf16
# (AVX2 only, no AVX512-BF16 / AMX) emulate it some 50x slower than fp32.
BF16_MIN_SPEEDUP = 1.2


@functools.cache
def resolve_precision(precision: str, device_type: str = "cpu") -> str:
    """The precision to run: `precision` itself ("fp32", "bf16"), or for "auto" the faster here (measured once).

    CUDA: bf16 where the GPU supports it. CPU: a 256 x 1152 x 256 matmul (the encoder-to-MLP layer's shape) timed in
    fp32 and in bf16; bf16 when it is at least BF16_MIN_SPEEDUP times faster."""
    if precision not in PRECISIONS:
        raise ValueError(f"unknown precision {precision!r}; choose from {PRECISIONS}")
    if precision != "auto":
        return precision
    if device_type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    seconds = {dtype: _matmul_seconds(dtype) for dtype in (torch.float32, torch.bfloat16)}
    return "bf16" if seconds[torch.float32] >= BF16_MIN_SPEEDUP * seconds[torch.bfloat16] else "fp32"


def _matmul_seconds(dtype: torch.dtype, repeats: int = 5) -> float:
    """Best time of one (256, 1152) @ (1152, 256) matmul in `dtype` on the CPU. Its operands come from a generator
    of its own: drawn from torch's global one, they shifted every draw after it, so a run's seed gave other initial
    weights depending on whether this process had resolved "auto" before (functools.cache: once per process)."""
    generator = torch.Generator().manual_seed(0)
    a = torch.randn(256, 1152, generator=generator).to(dtype)
    b = torch.randn(1152, 256, generator=generator).to(dtype)
    a @ b  # warm-up
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - start)
    return best


def input_dtype(precision: str, device: torch.device) -> torch.dtype:
    """The dtype networks take their images in: bf16 under bf16 precision (what autocast casts them to)."""
    return dtype_of(resolve_precision(precision, device.type))


def precision_autocast(precision: str, device: torch.device) -> AbstractContextManager[Any]:
    """bf16 autocast on `device` under bf16 precision, else a disabled one."""
    return autocast_of(resolve_precision(precision, device.type), device)


def dtype_of(resolved: str) -> torch.dtype:
    """The image dtype of a resolved precision ("fp32" or "bf16"; no lookup, so torch.compile traces it)."""
    return torch.bfloat16 if resolved == "bf16" else torch.float32


def autocast_of(resolved: str, device: torch.device) -> AbstractContextManager[Any]:
    """The autocast of a resolved precision. On a GPU without autocast's cache of cast weights, which CUDA graph
    capture does not allow."""
    return torch.autocast(
        device.type, dtype=torch.bfloat16, enabled=resolved == "bf16", cache_enabled=device.type != "cuda"
    )


def mlp(in_dim: int, hidden_dim: int, out_dim: int) -> nn.Sequential:
    """Two ReLU hidden layers of hidden_dim, then a linear head."""
    return nn.Sequential(
        nn.Linear(in_dim, hidden_dim), nn.ReLU(inplace=True),
        nn.Linear(hidden_dim, hidden_dim), nn.ReLU(inplace=True),
        nn.Linear(hidden_dim, out_dim),
    )  # fmt: skip


ENCODERS = ("paper", "strided")


class ConvEncoder(nn.Module):
    """The paper's conv net (Fig. 2), or a strided variant of it with the same output size.

    paper: two 5x5 'same' convs with `filters` filters, each followed by a 2x2 max-pool and a ReLU; flatten.
    The paper applies ReLU before the pool; max-pool and ReLU are both monotone, so they commute and
    relu(pool(x)) == pool(relu(x)) exactly, with the ReLU on a quarter of the values.
    strided: two 4x4 convs with stride 2 in place of conv + pool (as in DrQ's and Dreamer's encoders): the
    same 12x12 x filters output at 48 px at a sixth of the arithmetic; measured on the 2-core CPU, forward
    and backward of the pair take about a quarter of the time of the paper's (which runs its 8-channel
    convs at full resolution).
    """

    def __init__(self, image_size: int, filters: int, architecture: str = "paper") -> None:
        super().__init__()
        if architecture not in ENCODERS:
            raise ValueError(f"unknown encoder {architecture!r}; one of {', '.join(ENCODERS)}")
        self.strided = architecture == "strided"
        if self.strided:  # 4x4, stride 2, pad 1: halves the side exactly, like conv + 2x2 pool
            self.conv1 = nn.Conv2d(3, filters, 4, stride=2, padding=1)
            self.conv2 = nn.Conv2d(filters, filters, 4, stride=2, padding=1)
        else:
            self.conv1 = nn.Conv2d(3, filters, 5, padding=2)
            self.conv2 = nn.Conv2d(filters, filters, 5, padding=2)
        side = image_size // 2 // 2
        self.output_dim = filters * side * side

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        if self.strided:
            x = F.relu(self.conv1(images))
            x = F.relu(self.conv2(x))
        else:
            x = F.relu(F.max_pool2d(self.conv1(images), 2))
            x = F.relu(F.max_pool2d(self.conv2(x), 2))
        return x.flatten(1)


class SharedEncoder(nn.Module):
    """The conv net shared by actor and critics, then (feature_dim > 0) Linear + LayerNorm + tanh to
    feature_dim features, as in SAC-AE and DrQ: the heads' first layers shrink from conv-output-size inputs
    to feature_dim inputs, which is most of the heads' arithmetic."""

    def __init__(self, image_size: int, filters: int, architecture: str, feature_dim: int) -> None:
        super().__init__()
        self.conv = ConvEncoder(image_size, filters, architecture)
        self.projection = (
            nn.Sequential(nn.Linear(self.conv.output_dim, feature_dim), nn.LayerNorm(feature_dim), nn.Tanh())
            if feature_dim > 0
            else nn.Identity()
        )
        self.output_dim = feature_dim if feature_dim > 0 else self.conv.output_dim

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.projection(self.conv(images))


class Actor(nn.Module):
    """tanh-squashed Gaussian policy head; with its own encoder it takes images, without it features."""

    def __init__(self, feature_dim: int, action_dim: int, hidden_dim: int, encoder: ConvEncoder | None) -> None:
        super().__init__()
        self.encoder = encoder
        self.trunk = mlp(feature_dim, hidden_dim, 2 * action_dim)

    def forward(self, inputs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        features = self.encoder(inputs) if self.encoder is not None else inputs
        mean, log_std = self.trunk(features).float().chunk(2, dim=-1)
        return mean, log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)


class EnsembleLinear(nn.Module):
    """`members` independent Linear layers applied at once to (members, B, in_dim) inputs (one batched matmul),
    each initialised as nn.Linear would be."""

    def __init__(self, members: int, in_dim: int, out_dim: int) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.empty(members, in_dim, out_dim))
        self.bias = nn.Parameter(torch.empty(members, 1, out_dim))
        bound = 1.0 / math.sqrt(in_dim)  # nn.Linear's default: U(-1/sqrt(in), 1/sqrt(in)) for weight and bias
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        return torch.baddbmm(self.bias, inputs, self.weight)


class Critic(nn.Module):
    """Twin Q-functions; with their own encoders (one each) they take images, without them features.

    The two Q MLPs (two ReLU hidden layers, with `layer_norm` a LayerNorm before each ReLU, then a linear head) are
    independent networks stored as one ensemble of 2, so each layer of both runs as one batched matmul: the same
    maths as two nn.Sequential MLPs with half the operator calls, which is what a small MLP at batch 256 costs on a
    CPU.
    """

    def __init__(
        self, feature_dim: int, action_dim: int, hidden_dim: int, encoders: tuple[ConvEncoder, ConvEncoder] | None,
        layer_norm: bool = False,
    ) -> None:  # fmt: skip
        super().__init__()
        self.layer_norm = layer_norm
        self.encoders = nn.ModuleList(encoders) if encoders is not None else None
        self.layers = nn.ModuleList([
            EnsembleLinear(2, feature_dim + action_dim, hidden_dim),
            EnsembleLinear(2, hidden_dim, hidden_dim),
            EnsembleLinear(2, hidden_dim, 1),
        ])  # fmt: skip
        self._register_load_state_dict_pre_hook(_twin_mlps_to_ensemble)

    def forward(self, inputs: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.encoders is None:
            features = inputs.unsqueeze(0).expand(2, -1, -1)
        else:
            features = torch.stack([self.encoders[0](inputs), self.encoders[1](inputs)])
        action = action.to(features.dtype).unsqueeze(0).expand(2, -1, -1)
        x = torch.cat([features, action], dim=-1)
        for layer in self.layers[:2]:
            x = layer(x)
            if self.layer_norm:  # each member's hidden units normalised alone (the next layer holds the affine)
                x = F.layer_norm(x, x.shape[-1:])
            x = F.relu(x)
        q = self.layers[2](x).float().squeeze(-1)
        return q[0], q[1]


TWIN_MLP_INDICES = (0, 2, 4)
"""Where the ensemble's layers 0, 1, 2 were in the old q1 / q2 nn.Sequential MLPs (Linear, ReLU, Linear, ...)."""


def twin_to_ensemble(kind: str, q1_tensor: torch.Tensor, q2_tensor: torch.Tensor) -> torch.Tensor:
    """One old nn.Linear tensor of q1 and of q2 (a weight, a bias, or an Adam moment of one) -> the ensemble's."""
    if kind == "weight":  # nn.Linear stores (out, in); the ensemble (in, out)
        return torch.stack([q1_tensor.t(), q2_tensor.t()])
    return torch.stack([q1_tensor[None], q2_tensor[None]])


def _twin_mlps_to_ensemble(state: dict[str, torch.Tensor], prefix: str, *_: object) -> None:
    """Checkpoints written before the ensemble layout (q1 and q2 as nn.Sequential MLPs) load unchanged."""
    for layer, sequential_index in enumerate(TWIN_MLP_INDICES):
        for kind in ("weight", "bias"):
            q1_name, q2_name = (f"{prefix}q{q}.{sequential_index}.{kind}" for q in (1, 2))
            if q1_name not in state:
                return
            state[f"{prefix}layers.{layer}.{kind}"] = twin_to_ensemble(kind, state.pop(q1_name), state.pop(q2_name))


class RewardClassifier(nn.Module):
    """f_psi(s): the paper's conv net with a single logit (always its own encoder)."""

    def __init__(self, image_size: int, filters: int, hidden_dim: int, architecture: str = "paper") -> None:
        super().__init__()
        self.encoder = ConvEncoder(image_size, filters, architecture)
        self.head = mlp(self.encoder.output_dim, hidden_dim, 1)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        *hidden_layers, logit_layer = self.head  # (unpacking, not slicing: no new Sequential per call)
        hidden = self.encoder(images)
        for layer in hidden_layers:
            hidden = layer(hidden)
        with torch.autocast(hidden.device.type, enabled=False):  # the logit itself in fp32 (256 -> 1: free)
            return logit_layer(hidden.float()).squeeze(-1)


def squashed_gaussian_sample(
    mean: torch.Tensor, log_std: torch.Tensor, deterministic: bool = False, generator: torch.Generator | None = None,
    noise: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """a = tanh(u), u = mean + std * eps, eps ~ N(0, 1) (reparameterised; eps from `generator`, default torch's, or
    the given `noise`, e.g. coloured); returns (a, log pi(a|s)) with the tanh correction.

    log pi(a|s) = log N(u; mean, std) - sum log(1 - tanh(u)^2), and log(1 - tanh(u)^2) is computed as
    2 (log 2 - u - softplus(-2u)) for numerical stability (SAC paper, appendix C).
    """
    if deterministic:
        u = mean
        noise = torch.zeros_like(mean)
    else:
        if noise is None:
            noise = torch.randn(mean.shape, generator=generator, device=mean.device, dtype=mean.dtype)
        else:  # (given noise: converted once, here; the updates' own draws are already in mean's dtype)
            noise = noise.to(mean.dtype)
        u = mean + log_std.exp() * noise
    gaussian = (-0.5 * noise.pow(2) - log_std - _HALF_LOG_2PI).sum(-1)
    correction = (2.0 * (_LOG_2 - u - F.softplus(-2.0 * u))).sum(-1)
    return torch.tanh(u), gaussian - correction
