"""Rigid transforms and extrinsics. STUB: being implemented."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from scanfuse.config import FusionConfig


@dataclass(frozen=True)
class Extrinsics:
    @classmethod
    def from_config(cls, config: FusionConfig) -> Extrinsics:
        return cls()
