# SPDX-License-Identifier: GPL-3.0-or-later
"""Long calls cut into steps, for a modal operator (one step per TIMER event, Esc cancels) or a
plain loop (scripts, ``blender -b``, where timers never fire).

A ``Steps`` runs a *work* generator function ``work(steps, *args)``: it yields ``(fraction done,
text)`` after each piece (a frame rendered, a camera extracted...) and returns the call's result.
Its first piece reads the scene and checks the input, so bad input fails at the first ``step``.
While it works it keeps ``steps.kept`` saying what stays if it is stopped now; ``cancel`` closes
the generator (its ``finally`` blocks tidy up; what was written stays) and returns that line.
bpy is touched only by the thread that calls ``step`` (Blender's main thread).
"""

from __future__ import annotations


class Steps:
    def __init__(self, work, *args, **kwargs):
        self.name = getattr(work, "__name__", "work")
        self.fraction = 0.0
        self.text = ""
        self.kept = ""  # set by the work: what stays on disk / in the scene if it stops now
        self.result = None
        self.finished = False
        self.cancelled = False
        self._gen = work(self, *args, **kwargs)

    def step(self) -> bool:
        """Do one piece. False once the work is finished (``result`` is set). An error of the work
        is raised here; the work is over then (its ``finally`` blocks have run)."""
        if self.finished:
            return False
        try:
            self.fraction, self.text = next(self._gen)
        except StopIteration as stop:
            self.result = stop.value
            self.finished = True
            self.fraction = 1.0
            return False
        except BaseException:
            self.finished = True
            raise
        return True

    def run(self, progress=None):
        """All steps to the end; ``progress(fraction)`` whenever the fraction done changes (1.0 at the
        end). Returns the result."""
        last = None
        while self.step():
            if progress is not None and self.fraction != last:
                progress(self.fraction)
                last = self.fraction
        if progress is not None:
            progress(1.0)
        return self.result

    def cancel(self) -> str:
        """Stop where the work is; returns one line saying what was kept."""
        if not self.finished:
            self._gen.close()
            self.finished = True
            self.cancelled = True
        return self.kept or "nothing was changed"
