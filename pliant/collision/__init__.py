"""Contact: ground plane (more colliders and the hash-grid broad phase follow)."""

from ._ground import ground_contact

__all__ = ["ground_contact"]
