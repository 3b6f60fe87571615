"""Architecture spec strings (`V8:sigmoid-D32-D32-D8-V`), named presets and activations.

A leaf module (no activelearn imports): the config validates `arch` with it and the networks build
from it, so neither has to import the other.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

ACTIVATIONS: tuple[str, ...] = ("tanh", "sigmoid", "elu", "relu", "selu", "softplus")

# Named architectures. Tokens: V = variational (Bayesian) layer, D = dense layer, number = width,
# optional ":activation"; the last token has no width and produces the Gaussian head's parameters.
ARCH_PRESETS: dict[str, str] = {
    # The reference study's hybrid (3D-2V): saturating first variational layer, relu dense layers.
    "reference": "V8:sigmoid-D32:relu-D32:relu-D8:relu-V",
    # Chosen by measurement (experiments/investigations/model_selection.py): a dense relu feature extractor
    # and a variational read-out (the last two layers). Relu features grow linearly away from the data, so the
    # read-out's spread grows too: novelty ratio ~20 vs ~1.1 for `reference`, in-between (gap) ratio ~3.7; as
    # accurate as the alternatives and faster to train than D32-V32-V16-V.
    "default": "D64:relu-D64:relu-V16:relu-V",
}



_TOKEN = re.compile(r"^(?P<kind>[VD])(?P<width>\d+)?(?::(?P<act>[a-z]+))?$")


@dataclass(frozen=True)
class LayerSpec:
    """One layer of a spec: variational or dense, width (None = head layer), activation (None = default)."""

    variational: bool
    width: int | None
    activation: str | None


def resolve_arch(arch: str) -> str:
    """Return the spec string of a preset name, or `arch` itself when it is already a spec."""
    return ARCH_PRESETS.get(arch, arch)


def parse_arch(arch: str) -> list[LayerSpec]:
    """Parse a spec string or preset name into layers; raise ValueError naming the bad token."""
    spec = resolve_arch(arch.strip())
    tokens = spec.split("-")
    if not tokens or tokens == [""]:
        raise ValueError(f"empty architecture {arch!r}")
    layers: list[LayerSpec] = []
    for i, token in enumerate(tokens):
        m = _TOKEN.match(token.strip())
        if m is None:
            raise ValueError(
                f"bad token {token!r} in {arch!r}: expected V or D, an optional width and ':activation'"
                f" (presets: {', '.join(ARCH_PRESETS)})"
            )
        width = int(m["width"]) if m["width"] else None
        act = m["act"]
        last = i == len(tokens) - 1
        if act is not None and act not in ACTIVATIONS:
            raise ValueError(f"unknown activation {act!r} in token {token!r}; choose from {ACTIVATIONS}")
        if last and (width is not None or act is not None):
            raise ValueError(
                f"the last token {token!r} feeds the Gaussian head: give it no width or activation"
            )
        if not last and (width is None or width < 1):
            raise ValueError(f"hidden token {token!r} needs a width >= 1")
        layers.append(LayerSpec(m["kind"] == "V", width, act))
    return layers
