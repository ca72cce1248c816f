"""Which controller is which hand, for the three-point readers (A-Frame motion capture, Beat Saber
replays: FORMATS.md §2.6, §2.7): from where the controllers are seen from the headset, or as the
file labels them.

A file's left / right label is not always the hand: the A-Frame recordings `grabLeft.json` and
`grabRight.json` label their entities `left` / `right` while the Gamepad API's `hand` of each says
the other side. What a person holds in the right hand is on the headset's right most of the time
(arms cross now and then, not for most of a take), so by default that decides; the labels decide
when the geometry does not (too few frames with the controllers clearly apart sideways, or no clear
majority), and `hands="labels"` / `"swapped"` make the choice explicit.
"""

from __future__ import annotations

import numpy as np

from ...core import transforms as tf
from ...core.errors import BodyCalError
from ..model import ROLES_LIST

HANDS = ("geometry", "labels", "swapped")
SIDE_APART_M = 0.05  # controllers closer than this sideways (seen from the headset) say nothing
CLEAR_SHARE = 0.6  # the side a controller is on in at least this share of the telling frames
MIN_FRAMES = 30  # fewer telling frames than this: the geometry does not decide


def check_hands(hands: str, source: str) -> str:
    if hands not in HANDS:
        raise BodyCalError(f"'{hands}' is not a way to tell the hands", source=source, field="hands",
                           hint=f"use one of {', '.join(HANDS)}")
    return hands


def right_share(head_pos, head_rot, a_pos, b_pos, valid) -> tuple[float, int]:
    """(share, frames): among the frames where all three are tracked (`valid`, (F,)) and the two
    controllers are more than SIDE_APART_M apart along the headset's right axis (its local +X in
    the internal frame), the share where controller `a` is on the right of `b`; and how many such
    frames there are (share 0.5 when none)."""
    right = tf.quat_to_matrix(np.asarray(head_rot, float))[..., :, 0]
    side = np.einsum("fi,fi->f", np.asarray(a_pos, float) - np.asarray(b_pos, float), right)
    telling = valid & (np.abs(side) > SIDE_APART_M)
    n = int(telling.sum())
    return (float((side[telling] > 0).mean()) if n else 0.5), n


def choose_hands(hands: str, labelled_right: int | None, share: float, frames: int, names: tuple[str, str],
                 head: str) -> tuple[int | None, str]:
    """The index (0 or 1) of the controller that is the right hand (None: not told), and a note
    saying how it was chosen. `labelled_right`: the one the file labels right (None: no usable
    label); `share`, `frames`: `right_share` of controller 0 against controller 1."""
    def seen(k: int) -> str:  # how often controller k is on the right of the other
        part = share if k == 0 else 1 - share
        return (f"'{names[k]}' is right of '{names[1 - k]}' as the {head} sees them in {100 * part:.0f} % of "
                f"{frames} frames")

    by_geometry = None
    if frames >= MIN_FRAMES and max(share, 1 - share) >= CLEAR_SHARE:
        by_geometry = 0 if share > 0.5 else 1
    if hands == "geometry" and by_geometry is not None:
        agree = "" if labelled_right is None else (
            ", as the file labels them" if labelled_right == by_geometry else ", against the file's labels")
        return by_geometry, f"hands from where they are: {seen(by_geometry)}: the right hand{agree}"
    if labelled_right is None:
        return None, (f"hands not told apart: no left / right label, and {seen(0)} (give each its role in "
                      f"{ROLES_LIST})")
    right = labelled_right if hands != "swapped" else 1 - labelled_right
    why = {"labels": "as the file labels them", "swapped": "the file's labels swapped",
           "geometry": f"as the file labels them (where they are does not decide: {seen(labelled_right)})"}[hands]
    return right, f"hands {why}: '{names[right]}' is the right hand"
