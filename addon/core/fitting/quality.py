"""The simulation quality a fit chooses (issue 20): a ladder of warm-started rungs.

Blender's cloth takes ``quality`` solver steps per frame; too few, and a soft cloth moves like a
stiffer one; more cost time in proportion. Nobody knows the right value for a real cloth, so where
the user did not fix it, the fit's main search runs at a start quality and then *rungs*: short
CMA-ES runs at neighbouring qualities of ``QUALITY_LADDER``, each warm-started from the best so far.
One rung above the start, then upwards while the highest rung tried is the one the choice would take
(it fits more than ``QUALITY_TOLERANCE`` better than every lower one), then one rung below the start.
The choice is the lowest quality whose training error is within ``QUALITY_TOLERANCE`` of the best
tried: what the images can tell apart, at the least cost. (Until 2026-11-26 the climb needed a rung
``QUALITY_CLEARLY_BETTER``, 10 %, better: a rung 5 to 10 % better was chosen and the one above it never
tried, while the fit's diagnosis blamed the quality.)

``Ladder`` is plain decisions on numbers (which quality next, which is chosen), kept apart from the
job that runs the rungs, so it is tested on its own and its state is plain JSON in checkpoints.
"""

from __future__ import annotations

from .. import defaults as D
from ..errors import ClothFitError


class Ladder:
    """``tried``: quality -> best training error found there (sum of E_sil over the images)."""

    def __init__(
        self,
        start: int,
        rungs=D.QUALITY_LADDER,
        tolerance: float = D.QUALITY_TOLERANCE,
        clearly: float = D.QUALITY_CLEARLY_BETTER,
        max_rungs: int = D.QUALITY_RUNGS_RESERVED,
        probe_only: bool = False,
    ):
        self.rungs = sorted(set(int(q) for q in rungs) | {int(start)})
        self.start = int(start)
        self.tolerance = float(tolerance)
        self.clearly = float(clearly)
        self.max_rungs = int(max_rungs)
        self.probe_only = bool(probe_only)  # --backend blender: try one rung up, keep the scene's quality
        self.tried: dict[int, float] = {}
        self.order: list[int] = []

    def record(self, quality: int, error: float) -> None:
        q = int(quality)
        if q not in self.order:
            self.order.append(q)
        e = float(error)
        self.tried[q] = min(e, self.tried.get(q, float("inf")))

    def _above(self, q):
        i = self.rungs.index(q)
        return self.rungs[i + 1] if i + 1 < len(self.rungs) else None

    def _below(self, q):
        i = self.rungs.index(q)
        return self.rungs[i - 1] if i > 0 else None

    def next(self) -> int | None:
        """The next quality to try, or None when the ladder is done."""
        if self.start not in self.tried or len(self.order) - 1 >= self.max_rungs:
            return None
        if self.probe_only:
            up = self._above(self.start)
            return up if up is not None and up not in self.tried else None
        top = max(self.tried)
        up = self._above(top)
        if len(self.tried) == 1 and up is not None:  # first rung: one above the start
            return up
        lower = [e for q, e in self.tried.items() if q < top]
        climbing = bool(lower) and self.chosen() == top  # the top rung is the choice: the one above may be better
        if climbing and up is not None:
            return up
        down = self._below(min(self.tried))
        if down is not None and min(self.tried) == self.start:  # one rung below the start, once
            return down
        return None

    def chosen(self) -> int:
        """The lowest quality tried whose error is within ``tolerance`` of the best."""
        if not self.tried:
            raise ClothFitError("quality ladder: nothing tried")
        if self.probe_only:
            return self.start
        best = min(self.tried.values())
        ok = [q for q, e in self.tried.items() if e <= (1.0 + self.tolerance) * best]
        return min(ok)

    def clearly_better_above(self) -> tuple[int, float] | None:
        """probe_only: (quality, error ratio to the start) of a higher rung that fits clearly better, else None."""
        base = self.tried.get(self.start)
        for q in sorted(self.tried):
            if q > self.start and base and self.tried[q] < (1.0 - self.clearly) * base:
                return q, self.tried[q] / base
        return None

    def state_dict(self) -> dict:
        return {
            "start": self.start,
            "rungs": self.rungs,
            "tolerance": self.tolerance,
            "clearly": self.clearly,
            "max_rungs": self.max_rungs,
            "probe_only": self.probe_only,
            "tried": [[q, self.tried[q]] for q in self.order],
        }

    @classmethod
    def from_state(cls, d: dict) -> Ladder:
        try:
            lad = cls(d["start"], d["rungs"], d["tolerance"], d["clearly"], d["max_rungs"], d["probe_only"])
            for q, e in d["tried"]:
                lad.record(int(q), float(e))
        except (KeyError, TypeError, ValueError) as e:
            raise ClothFitError(f"checkpoint: bad quality ladder state ({e})") from None
        return lad

    def describe(self, n_images: int) -> dict:
        """The result's ``quality_choice``: every rung's training error (mean E_sil %) and the choice."""
        tried = [{"quality": q, "train_E_sil_pct": 100.0 * self.tried[q] / n_images} for q in self.order]
        d = {
            "start": self.start,
            "chosen": self.chosen(),
            "tolerance": self.tolerance,
            "tried": sorted(tried, key=lambda r: r["quality"]),
            "rule": (
                "kept the scene's quality; one rung above it tried"
                if self.probe_only
                else f"the lowest quality within {100 * self.tolerance:g} % of the best training error"
            ),
        }
        if self.probe_only:
            up = self.clearly_better_above()
            if up:
                d["advice"] = (
                    f"quality {up[0]} fits {100 * (1 - up[1]):.0f} % better than the scene's "
                    f"{self.start}: refit with --quality {up[0]} (or --quality auto)"
                )
        return d
