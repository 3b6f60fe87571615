"""What the local workers' fork server imports (by name, `studies.processes.QUIET_PRELOAD`): importing
it imports the workers' modules with Ctrl-C ignored, and keeps workers orphaned at their start quiet."""

from activelearn.studies.processes import preload_quietly, quiet_orphans

preload_quietly()
quiet_orphans()
