"""Fake table stage."""

from arroyo_fake_stages.tally import STAGE

__all__ = ["STAGE"]
