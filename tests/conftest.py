"""The suite's environment: commands print their timed progress lines (`cli.progress`, every 10 s once a
command runs longer) only in the tests that check them (they set their own interval), so what a test reads of a
command's output does not depend on how loaded the machine is."""

import os

os.environ.setdefault("SLAMOBS_PROGRESS_EVERY", "1e9")
