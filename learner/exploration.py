"""Temporally correlated exploration noise (Eberhard et al., "Pink Noise Is All You Need", ICLR 2023).

The acting policy draws a = tanh(mean + std * eps). With SAC's i.i.d. eps, a policy that is still near its start
(mean ~ 0, wide std) jitters in place: its steps average out, and the pusher's hand touches the mug in 18% of
episodes (`bench/exploration.py`; pink noise: 39%). Coloured eps keeps each step's distribution, N(0, 1), but
makes the steps of an episode agree with each other, so the hand wanders. Its power spectrum falls as 1 / f^beta:
beta 0 is white noise (SAC's own), 1 pink, 2 red (a random walk). Each episode draws a new sequence.
"""

import math

import numpy as np
import torch


def colored_noise(beta: float, steps: int, dims: int, generator: torch.Generator) -> torch.Tensor:
    """(steps, dims) Gaussian noise whose power spectral density falls as f^-beta along the steps, each entry of
    unit variance, on the generator's device.

    Each dimension is the inverse real FFT of independent complex Gaussian coefficients scaled by f^(-beta / 2),
    the zero frequency taking the lowest other frequency's scale (Timmer & Koenig 1995)."""
    frequencies = torch.fft.rfftfreq(steps, device=generator.device)
    frequencies[0] = 1.0 / steps
    scale = frequencies.pow(-beta / 2.0)
    real, imaginary = torch.randn((2, len(frequencies), dims), generator=generator, device=generator.device)
    imaginary[0] = 0.0  # the zero frequency is real, and so is the Nyquist frequency of an even length
    if steps % 2 == 0:
        imaginary[-1] = 0.0
    noise = torch.fft.irfft(torch.complex(real, imaginary) * scale[:, None], n=steps, dim=0)
    # Var of each step: (sum over coefficients of |scale|^2 E|c|^2, the inner ones counted twice) / steps^2
    inner = scale[1:-1] if steps % 2 == 0 else scale[1:]
    variance = scale[0] ** 2 + 4 * inner.pow(2).sum() + (scale[-1] ** 2 if steps % 2 == 0 else 0.0)
    return noise / (variance.sqrt() / steps)


def uniform_of(noise: torch.Tensor) -> torch.Tensor:
    """N(0, 1) noise mapped to U(-1, 1) through the Gaussian CDF (2 Phi(x) - 1 = erf(x / sqrt 2)): the warm-up's
    uniform actions, correlated as the noise is."""
    return torch.erf(noise / math.sqrt(2.0))


def warm_up_action(noise: torch.Tensor | None, rng: np.random.Generator, dims: int) -> np.ndarray:
    """A warm-up action in [-1, 1]^dims: i.i.d. uniform from `rng`, or this step's coloured eps made uniform."""
    if noise is None:
        return rng.uniform(-1.0, 1.0, dims).astype(np.float32)
    return uniform_of(noise).cpu().numpy()


class EpisodeNoise:
    """The coloured eps of one env's episodes: `next` gives each step's (dims,) draw, in order; `restart` draws a
    new sequence (at each episode's start; a longer episode than `steps` goes on into a new sequence)."""

    def __init__(self, beta: float, steps: int, dims: int, generator: torch.Generator) -> None:
        self.beta, self.steps, self.dims, self.generator = beta, steps, dims, generator
        self.sequence = torch.zeros((0, dims), device=generator.device)
        self.position = 0

    def restart(self) -> None:
        self.sequence = colored_noise(self.beta, self.steps, self.dims, self.generator)
        self.position = 0

    def next(self) -> torch.Tensor:
        if self.position >= len(self.sequence):
            self.restart()
        self.position += 1
        return self.sequence[self.position - 1]
