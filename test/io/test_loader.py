"""Reading several flights at once: an unreadable one raises, or with skip_bad is left out and named."""

import pytest

from quad_modelling.errors import DataError
from quad_modelling.io.loader import load_flights
from quad_modelling.io.matlog import write_matlog
from test.conftest import synthetic_log


def test_load_flights_skips_and_names_a_bad_file_only_when_asked(tmp_path):
    good = write_matlog(synthetic_log(n=300, vehicle="linkquad"), tmp_path / "good.mat")
    bad = tmp_path / "bad.mat"  # missing
    with pytest.raises(DataError, match="bad.mat"):
        load_flights([good, bad])
    flights, skipped = load_flights([good, bad], skip_bad=True)
    assert [len(f) for f in flights] == [300] and flights[0].meta.vehicle == "linkquad"
    assert len(skipped) == 1 and "bad.mat" in skipped[0]
