"""A job's files and needs: the run directory it writes and the reader of it, the checkpoint, the
lock that keeps one process per directory, and the memory and time it asks for. ``lock`` and
``resources`` import no torch, so ``train.py`` can use them before torch loads."""
