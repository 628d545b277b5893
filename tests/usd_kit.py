"""USD test kit: validity assertion on top of pxr.UsdValidation and a Tf-diagnostics check."""

from __future__ import annotations

from pxr import Usd

import holousd


def assert_valid_usd(stage: Usd.Stage) -> None:
    """Fail with every issue listed unless ``stage`` passes all OpenUSD validators and holousd's rules."""
    report = holousd.validate(stage)
    assert report.ok, "\n".join(str(i) for i in report.issues)


def assert_no_tf_diagnostics(capfd) -> None:  # noqa: ANN001 - pytest's capfd fixture
    """Fail if USD printed a Tf warning or error on the process's stderr since the last capture."""
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if "Warning" in line or "Error" in line or "Coding" in line]
    assert not lines, "USD emitted diagnostics:\n" + "\n".join(lines)
