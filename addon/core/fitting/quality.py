"""The simulation quality a fit chooses: a ladder of warm-started rungs.

Blender's cloth takes ``quality`` solver steps per frame; too few, and a soft cloth moves like a
stiffer one; more cost time in proportion. Nobody knows the right value for a real cloth, so where
the user did not fix it, the fit's main search runs at a start quality and then *rungs*: short
CMA-ES runs at neighbouring qualities of ``QUALITY_LADDER``, each warm-started from the best so far.
One rung above the start, then upwards while the highest rung tried is the one the choice would take
(it fits more than ``QUALITY_TOLERANCE`` better than every lower one). Where the climb took the choice
above the start and stopped with the rung above the choice tried, one *refining* rung between the two
(their geometric mean: 10 between 8 and 12, 15 between 12 and 18), for a cloth whose quality lies
between two rungs; otherwise one rung below the start (below a start the climb left behind by more
than the tolerance nothing would be chosen). The choice is the lowest quality whose training error is
within ``QUALITY_TOLERANCE`` of the best tried: what the images can tell apart, at the least cost.
In a "cma-staged" fit each rung is staged too (``FitJob._rung_optimizer``: the strong settings and the
time offset first, from the warm start). Until 2026-11-26 the climb needed a rung
``QUALITY_CLEARLY_BETTER`` (10 %) better, and there was no refining rung and no staged rung
(docs/fit_goals.md, the time goal).

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
        self.tried: dict[int, float] = {}  # the ladder's rungs, and refining rungs between two of them
        self.order: list[int] = []

    def record(self, quality: int, error: float) -> None:
        q = int(quality)
        if q not in self.order:
            self.order.append(q)
        e = float(error)
        self.tried[q] = min(e, self.tried.get(q, float("inf")))

    def above(self, q: int) -> int | None:
        """The rung above quality ``q`` (one of the rungs), or None at the top."""
        i = self.rungs.index(q)
        return self.rungs[i + 1] if i + 1 < len(self.rungs) else None

    def _below(self, q):
        i = self.rungs.index(q)
        return self.rungs[i - 1] if i > 0 else None

    def allows(self, quality: int) -> bool:
        """A quality this ladder may try: one of its rungs, or a refining rung between two of them."""
        return self.rungs[0] <= int(quality) <= self.rungs[-1]

    def _refining(self) -> int | None:
        """Between the choice, climbed to above the start, and the rung above it (both tried, the latter
        not chosen): their geometric mean (15 between 12 and 18), if it is a quality not yet tried."""
        c = self.chosen()  # above the start (next() asks only then)
        if c not in self.rungs:
            return None
        up = self.above(c)
        if up is None or up not in self.tried:
            return None
        m = int(round((c * up) ** 0.5))
        return m if c < m < up and m not in self.tried else None

    def next(self) -> int | None:
        """The next quality to try, or None when the ladder is done."""
        if self.start not in self.tried or len(self.order) - 1 >= self.max_rungs:
            return None
        if self.probe_only:
            up = self.above(self.start)
            return up if up is not None and up not in self.tried else None
        top = max(self.tried)
        up = self.above(top)
        if len(self.tried) == 1 and up is not None:  # first rung: one above the start
            return up
        lower = [e for q, e in self.tried.items() if q < top]
        climbing = bool(lower) and self.chosen() == top  # the top rung is the choice: the one above may be better
        if climbing and up is not None:
            return up
        if self.chosen() > self.start:  # climbed: refine between the choice and the rung above it
            return self._refining()
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
