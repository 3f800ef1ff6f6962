"""Reasons are codes with numbers, worded in one place (bldc/reasons.py): every code renders with
its numbers, a wrong code or a missing number is refused at once, and a saved sentence (a file
written before the codes) reads back as free text worded exactly as it was."""

from __future__ import annotations

import json
import re
import string
from pathlib import Path

import pytest

from bldc.reasons import FREE_TEXT, NUMBERS_OF, WORDING, Reason, words
from hil.calibration.corrections import Corrections


@pytest.mark.parametrize("code", sorted(WORDING))
def test_every_code_renders_with_its_numbers(code):
    numbers = dict.fromkeys(NUMBERS_OF[code], 1.0)
    text = words(Reason(code, numbers))
    assert text and "{" not in text and "}" not in text
    # each number is in the sentence: a changed number changes the words
    for name in numbers:
        assert words(Reason(code, {**numbers, name: 37.0})) != text, (code, name)


def test_the_codes_are_numbered_and_each_wording_is_used_once():
    assert all(code == FREE_TEXT or re.fullmatch(r"(CAL|GAP|TWIN)-\d{3}", code) for code in WORDING)
    assert len(set(WORDING.values())) == len(WORDING)


def test_the_renderer_formats_lists_dicts_and_nested_reasons():
    bound = Reason("CAL-010", {"bound_us": 50.0})
    assert words(Reason("CAL-003", {"value_us": 123.456, "bound_us": 50.0, "bound_why": bound})) == (
        "123.5 us is beyond the bound 50 us (stated maximum 50 us)"
    )
    assert words(Reason("CAL-001", {"poles": [1, 3], "offsets_deg_e": [40.0, -35.04], "bound_deg_e": 30.0})) == (
        "pole(s) 1, 3 at +40.0, -35.0 deg e, beyond the controller's bound +-30 deg e (a pole count that is not the "
        "motor's, or a speed change inside a segment taken as steady); the table is not written"
    )
    assert words(Reason("CAL-002", {"offsets_deg_e": {"A": 35.0, "C": -40.0}, "bound_deg_e": 30.0})).startswith(
        "A +35.0, C -40.0 deg e beyond +-30: "
    )


def test_a_wrong_code_or_number_is_refused_naming_it():
    with pytest.raises(KeyError, match="CAL-999"):
        Reason("CAL-999")
    with pytest.raises(ValueError, match="CAL-003.*bound_why"):
        Reason("CAL-003", {"value_us": 1.0, "bound_us": 2.0})


def test_a_free_text_reason_from_an_old_file_round_trips(tmp_path):
    """A correction table saved with sentences: read, its reasons are free text, written again the same."""
    saved = Corrections(undetermined={"conditioning_delay_s": Reason("CAL-040"),
                                      "pole_offset_deg_e": Reason("CAL-050", {"poles_seen": 3, "poles": 4})})
    path = saved.write_json(tmp_path / "old.json")
    data = json.loads(path.read_text())
    assert data["undetermined"]["pole_offset_deg_e"] == "edges of only 3 of 4 poles; record whole mechanical turns"
    read = Corrections.from_json_dict(data)
    why = read.undetermined["pole_offset_deg_e"]
    assert why == Reason(FREE_TEXT, {"text": data["undetermined"]["pole_offset_deg_e"]})
    assert read.to_json_dict()["undetermined"] == data["undetermined"]
    assert Reason.from_json("any {braces} kept") == Reason(FREE_TEXT, {"text": "any {braces} kept"})
    assert words(Reason.from_json("any {braces} kept")) == "any {braces} kept"


def test_every_code_the_gap_diagnosis_and_the_twin_use_is_worded():
    """The codes written in hil/gap and hil/twin (and the calibration codes they reuse) are all in
    WORDING, so each of their sentences is worded there and nowhere else."""
    root = Path(__file__).resolve().parents[1] / "hil"
    used = {code for folder in ("gap", "twin") for path in (root / folder).glob("*.py")
            for code in re.findall(r"[\"']((?:CAL|GAP|TWIN)-\d{3})[\"']", path.read_text(encoding="utf-8"))}
    assert {c.split("-")[0] for c in used} == {"GAP", "TWIN"} and len(used) > 60
    assert used <= set(WORDING), sorted(used - set(WORDING))


def _worded(text: str) -> bool:
    """Whether ``text`` is the wording of some code (free text aside) with some numbers."""
    def pattern(template):
        return "".join(re.escape(lit) + ("(.*?)" if name is not None else "")
                       for lit, name, _, _ in string.Formatter().parse(template))
    return any(re.fullmatch(pattern(t), text, re.DOTALL) for c, t in WORDING.items() if c != FREE_TEXT)


def test_a_gap_diagnosis_json_holds_only_worded_sentences():
    """The sentences a diagnosis stores (what it does not assess, the pole pairs' source, the
    held-out method, each relevance floor's meaning) are each the wording of a code."""
    from hil.gap import diagnose
    from hil.gap.synthetic import KNOWN_MODEL
    from hil.gap.validate import make_case

    data = diagnose(make_case(["conditioning_delay"], snr=3.0, seed=101)[0], KNOWN_MODEL).to_json()
    sentences = data["not_assessed"] + [data["pole_pairs_source"], data["heldout_note"]] + [
        a["relevance"]["meaning"] for a in data["accepted"] + data["below_relevance"] if "relevance" in a]
    assert len(sentences) >= 8 and any("relevance" in a for a in data["accepted"])
    assert [s for s in sentences if not _worded(s)] == []
    assert not _worded("a sentence no code words")
