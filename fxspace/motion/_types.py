"""The ``Motion`` container: a skeleton (names, parents, rest offsets) plus per-frame root
translation and per-joint local rotations as unit quaternions.

Conventions (used by every reader, writer and `fxspace.forward_kinematics`):

- Lengths are in **metres**; the world is Y-up (CMU ASF/AMC and BVH both are).
- Joints are listed parents-first (``parents[j] < j``; the root has parent ``-1``).
  A joint sits at the *start* of its bone, as in BVH; ``offsets[j]`` is its rest
  position relative to its parent joint, in the parent's frame. End sites (bone tips)
  are joints too, with no channels and identity rotation.
- Quaternions are ``(w, x, y, z)``, Hamilton product, active rotations of column
  vectors: ``R_world[j] = R_world[parents[j]] @ R_local[j]`` and
  ``X[j] = X[parents[j]] + R_world[parents[j]] @ offsets[j]``; the root's position is
  ``root_translation + offsets[0]``.
- ``channels[j]`` keeps a BVH joint's channel names in file order (e.g.
  ``("Zrotation", "Yrotation", "Xrotation")``) so that `write_bvh` writes the
  Euler angles back in exactly that order.
"""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
from jaxtyping import Array, Float

__all__ = ["Motion"]


@dataclasses.dataclass(frozen=True)
class Motion:
    """A skeletal motion clip (a JAX pytree: the arrays are leaves, the skeleton is static).

    **Fields:**

    - ``names``: joint names, ``(J,)`` strings.
    - ``parents``: parent index per joint, ``-1`` for the root, parents first.
    - ``offsets``: ``(J, 3)`` rest offset of each joint from its parent, metres.
    - ``root_translation``: ``(T, 3)`` root translation per frame, metres.
    - ``rotations``: ``(T, J, 4)`` local rotation of each joint, unit quaternions ``(w, x, y, z)``.
    - ``rate``: frames per second.
    - ``channels``: per joint, the BVH channel names in file order (``()`` for end sites).
    """

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: Float[Array, "joints 3"]
    root_translation: Float[Array, "frames 3"]
    rotations: Float[Array, "frames joints 4"]
    rate: float
    channels: tuple[tuple[str, ...], ...]

    @property
    def num_frames(self) -> int:
        return int(np.shape(self.rotations)[-3])

    @property
    def num_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (``ValueError`` listing the names otherwise)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValueError(f"no joint named {name!r}; joints are {list(self.names)}") from None

    def frames(self, sl: slice) -> Motion:
        """A copy restricted to the frames ``sl`` (e.g. ``slice(None, None, 4)``)."""
        rate = self.rate
        if sl.step not in (None, 1):
            rate = self.rate / int(sl.step)
        return dataclasses.replace(
            self,
            root_translation=self.root_translation[sl],
            rotations=self.rotations[sl],
            rate=rate,
        )


jax.tree_util.register_dataclass(
    Motion,
    data_fields=["offsets", "root_translation", "rotations"],
    meta_fields=["names", "parents", "rate", "channels"],
)
