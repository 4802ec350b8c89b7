"""Settings of the sampler (:class:`SamplerConfig`) and the ring buffer's hard cap."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_validator

#: Hard cap of the ring buffer, whatever ``history_s`` and the poll rate.
MAX_BUFFER = 100_000


class SamplerConfig(BaseModel):
    """Settings of the sampler. Times in s, lengths in mm, angles in deg."""

    model_config = ConfigDict(extra="forbid")

    poll_interval_s: float = Field(
        default=0.0,
        ge=0,
        description="Time between the starts of two polls [s]; 0: as fast as the links allow.",
    )
    settle_s: float = Field(
        default=0.5, gt=0, description="Window in which the robot must be still [s]."
    )
    settle_tol_mm: float = Field(
        default=0.1,
        gt=0,
        description="Largest deviation of the cable length from the window mean [mm].",
    )
    settle_tol_deg: float = Field(
        default=0.01,
        gt=0,
        description="Largest deviation of each joint from the window mean [deg].",
    )
    capture_timeout_s: float = Field(
        default=10.0,
        gt=0,
        description="How long a manual capture waits for settling [s]; >= settle_s.",
    )
    stale_s: float = Field(
        default=0.5,
        gt=0,
        description="A reading older than this when paired, joint and length stamps "
        "further apart than this, or a gap between readings longer than this, is stale [s].",
    )
    min_readings: int = Field(
        default=5, ge=2, description="Fewest paired readings in a settled window [count]."
    )
    auto_new_pose_deg: float = Field(
        default=0.05,
        ge=0,
        description="Auto mode: a pose closer than this in every joint to a pose "
        "already captured in the campaign is not new [deg].",
    )
    history_s: float = Field(
        default=10.0,
        gt=0,
        description="Span of the ring buffer of paired readings [s]; >= settle_s.",
    )
    error_backoff_s: float = Field(
        default=0.2, ge=0, description="Pause after a device error before the next poll [s]."
    )

    @model_validator(mode="after")
    def _check(self) -> SamplerConfig:
        if self.capture_timeout_s < self.settle_s:
            raise ValueError("capture_timeout_s: must be >= settle_s")
        if self.history_s < self.settle_s:
            raise ValueError("history_s: must be >= settle_s")
        return self
