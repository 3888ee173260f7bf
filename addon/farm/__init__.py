"""Parallel workers for the CLI (never imports bpy): ``executors`` (Ray actors, or spawned processes
without Ray) and ``scene`` (the ``--backend blender`` evaluator: candidates simulated by Blender's
own solver on a user's .blend in worker processes, scored by the core)."""
