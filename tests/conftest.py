import os
import sys

# The tests' own helpers (geometry_helpers, fixture writers) import as plain modules.
sys.path.insert(0, os.path.dirname(__file__))

import hypothesis  # noqa: E402

# Property tests jit per example shape; keep them deterministic and within the CI budget.
hypothesis.settings.register_profile("jaxpose", max_examples=25, deadline=None, derandomize=True)
hypothesis.settings.load_profile("jaxpose")
