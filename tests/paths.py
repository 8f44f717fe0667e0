"""Where the tests find the repository and the real data beside it (`../shared/data`, absent in a user's clone)."""

from pathlib import Path

TESTS = Path(__file__).resolve().parent
REPO = TESTS.parent
SHARED_DATA = REPO.parent / "shared" / "data"
FORMATS = SHARED_DATA / "formats"  # small real files in the formats users bring
H36M_S1 = SHARED_DATA / "h36m_s1"  # Human3.6M S1 as distributed
