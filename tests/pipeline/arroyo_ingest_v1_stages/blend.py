"""Fake blend stage."""

from arroyo_fake_stages.blend import STAGE

__all__ = ["STAGE"]
