"""Campaign settings: defaults, the quick variant, and one clear error for every kind of mistake."""

from __future__ import annotations

from pathlib import Path

import pytest

from battlab.campaign.config import QUICK_LIBRARY_IDS, CampaignConfig, load, quick
from protocols.errors import InputError

STAGES = ("ocv", "sweep", "design", "conventional")


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "campaign.toml"
    p.write_text(text)
    return p


def test_defaults_and_values(tmp_path: Path) -> None:
    assert load(None) == CampaignConfig()
    c = load(
        write(tmp_path, '[design]\ncriterion = "E"\nprofiles_per_group = 3\n[stages]\nskip = ["conventional"]\n'),
        STAGES,
    )
    assert c.design.criterion == "E" and c.design.profiles_per_group == 3
    assert c.stages.skip == ("conventional",)
    assert c.campaign.truth == "nca18650-true"
    c = load(write(tmp_path, "[conventional]\nc_rates = [-2, 0.5]\n[validation]\nc_rates = [1]\n"))
    assert c.conventional.c_rates == (-2.0, 0.5) and c.validation.c_rates == (1.0,)


def test_quick_reduces_but_keeps_given_ids(tmp_path: Path) -> None:
    q = quick(CampaignConfig())
    assert q.quick and q.library.ids == QUICK_LIBRARY_IDS and q.design.profiles_per_group <= 2
    mine = quick(load(write(tmp_path, "[library]\nids = [3, 4]\n")))
    assert mine.library.ids == (3, 4)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[desing]\nM = 3\n", r"unknown section \[desing\] \(did you mean 'design'\?\)"),
        ("[design]\ncriterium = 'D'\n", r"design.criterium: unknown key \(did you mean 'criterion'\?\)"),
        ("[design]\ncriterion = 'Q'\n", r"design.criterion: expected one of D, A, E"),
        ("[design]\nprofiles_per_group = 'five'\n", r"profiles_per_group: expected a non-negative integer"),
        ("[stages]\nskip = ['sweeep']\n", r"unknown stage 'sweeep' \(did you mean 'sweep'\?\)"),
        ("[library]\nids = ['a']\n", r"library.ids: expected a list of int"),
        ("[design\n", r"not valid TOML"),
        ("[conventional]\nc_rates = [0, -1]\n", r"conventional.c_rates: expected a list of non-zero C-rates"),
    ],
)
def test_mistakes_are_one_clear_error(tmp_path: Path, text: str, message: str) -> None:
    p = write(tmp_path, text)
    with pytest.raises(InputError, match=message) as info:
        load(p, STAGES)
    assert str(p) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such campaign config"):
        load(tmp_path / "nope.toml")
