"""The retiming's error type (design §8)."""

from __future__ import annotations


class RetimeError(ValueError):
    """A retiming request that cannot be met (explained in the message)."""
