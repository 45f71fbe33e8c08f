"""Every measured number in the prose comes from a committed result file.

`docs/_scripts/check_numbers.py` reads README.md, docs/, benchmarks/README.md, the package and
integration READMEs and the model cards; a number with no declared source, or one that matches no value
of its sources at the precision shown, fails here with file:line. The other tests check that the
checker catches what it is for (a stale number, a missing source, a hand-edited generated block) and
leaves settings, versions and dates alone.
"""

import importlib.util
import re
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "docs" / "_scripts" / "check_numbers.py"
R = "benchmarks/results"


@pytest.fixture(scope="module")
def checker() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_numbers", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _page(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "page.md"
    path.write_text(text)
    return path


def test_every_number_in_the_docs_has_a_matching_source(checker: ModuleType) -> None:
    pages = checker.pages()
    # the files the issue names are all read
    names = {str(p.relative_to(ROOT)) for p in pages}
    for needed in (
        "README.md",
        "docs/speed-vs-accuracy.md",
        "packages/gaffer-nerf/README.md",
        "docs/tutorials/relight-nerf.md",
        "packages/gaffer-diffusion/src/gaffer_diffusion/weights/gaffer-tiny/MODEL_CARD.md",
    ):
        assert needed in names
    failures = [f for page in pages for f in checker.check_page(page)]
    assert not failures, "numbers without a matching source:\n" + "\n".join(failures)


def test_a_stale_number_fails_with_its_line(checker: ModuleType, tmp_path: Path) -> None:
    # gaffer-nerf's README once said 32.14 dB for the fixed 32^3 fit; nerf.json says 32.473
    page = _page(
        tmp_path,
        f"# x\n\n<!-- numbers-from: {R}/nerf.json -->\n\nThe fit scores 32.47 dB.\n"
        "Before it scored 32.14 dB.\n",
    )
    failures = checker.check_page(page)
    assert len(failures) == 1
    assert failures[0].startswith(f"{page}:6: 32.14 dB")


def test_a_number_without_a_source_fails(checker: ModuleType, tmp_path: Path) -> None:
    page = _page(tmp_path, "# x\n\nIt takes 4.2 s and scores 18.37 dB, 87% of the time.\n")
    failures = checker.check_page(page)
    assert [f.split(": ")[1] for f in failures] == ["4.2 s", "18.37 dB", "87%"]
    assert all("no numbers-from source declared" in f for f in failures)


def test_a_declaration_covers_its_section_only(checker: ModuleType, tmp_path: Path) -> None:
    page = _page(
        tmp_path,
        f"# x\n\n## a\n\n<!-- numbers-from: {R}/nerf.json -->\n\n32.47 dB\n\n## b\n\n32.47 dB\n",
    )
    failures = checker.check_page(page)
    assert len(failures) == 1 and failures[0].startswith(f"{page}:11: 32.47 dB")


def test_derived_forms_are_narrow(checker: ModuleType, tmp_path: Path) -> None:
    test06 = f"{R}/reshade_render_test06.json"
    ok = _page(
        tmp_path,
        f"<!-- numbers-from: {test06} -->\n# x\n\n"
        # a difference of a row's score and its input's (15.84 - 11.93), a share as a percent
        "It scores +3.91 dB over the input and is closer on 88% of pairs.\n",
    )
    assert checker.check_page(ok) == []
    bad = _page(tmp_path, f"<!-- numbers-from: {test06} -->\n# x\n\nIt scores +3.95 dB.\n")
    assert len(checker.check_page(bad)) == 1
    # a ratio's unit must fit the leaf: 17x must not match a 17.18 ms timing
    ratio = _page(
        tmp_path,
        f"<!-- numbers-from: {R}/envmap_filters.json -->\n# x\n\nabout 17× slower\n",
    )
    assert len(checker.check_page(ratio)) == 1


def test_settings_versions_and_dates_are_not_measurements(
    checker: ModuleType, tmp_path: Path
) -> None:
    page = _page(
        tmp_path,
        "# x\n\ngaffer-tiny 0.5.1 at 128 px, 50 steps, 3 views, a 512×256 map, lr `1e-4`, "
        "torch 2.13.0, on 2026-12-04 at 20:50 (§4.2, issue 18), 0.4 against 0.5, L1 8e-6.\n\n"
        "```bash\ngaffer-nerf fit x --lr 0.02 --steps 12.5\n```\n",
    )
    assert checker.check_page(page) == []


def test_a_missing_source_file_fails(checker: ModuleType, tmp_path: Path) -> None:
    page = _page(tmp_path, f"# x\n\n<!-- numbers-from: {R}/no_such.json -->\n\nplain text\n")
    failures = checker.check_page(page)
    assert failures and "is not a JSON file" in failures[0]


def test_a_hand_edited_generated_block_fails(checker: ModuleType, tmp_path: Path) -> None:
    readme = (ROOT / "README.md").read_text()
    open_, close = "<!-- generated: gaffer-tiny-headline -->", "<!-- /generated -->"
    block = open_ + readme.split(open_, 1)[1].split(close, 1)[0] + close
    # the block as generated passes without any declaration: its generator rebuilds it from files
    assert checker.check_page(_page(tmp_path, f"# x\n\n{block}\n")) == []
    # the first score of the sentence, raised by 0.10 dB
    first = re.search(r"(\d+)\.(\d\d) dB", block)
    assert first is not None
    bumped = f"{float(first.group(0)[:-3]) + 0.1:.2f} dB"
    edited = block.replace(first.group(0), bumped, 1)
    assert edited != block
    failures = checker.check_page(_page(tmp_path, f"# x\n\n{edited}\n"))
    assert any("headline differs" in f for f in failures)


def test_allowlist_skips_its_numbers_and_fails_when_stale(
    checker: ModuleType, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    page = _page(tmp_path, "# x\n\nThe sun is a 0.53-degree disc.\n")
    monkeypatch.setitem(checker.NOT_MEASURED, str(page), {"0.53": "a constant"})
    assert checker.check_page(page) == []
    page.write_text("# x\n\nThe sun is a disc.\n")
    failures = checker.check_page(page)
    assert len(failures) == 1 and "0.53: listed in NOT_MEASURED" in failures[0]


def test_no_measured_number_is_waiting_for_a_source(checker: ModuleType) -> None:
    # the list of unsourced numbers is gone: every measured number has a result file (or a pin)
    assert not hasattr(checker, "KNOWN_UNSOURCED")
    for why in (w for page in checker.NOT_MEASURED.values() for w in page.values()):
        assert "no result file" not in why


DEMO = f"{R}/demo_example_gaffer-tiny-0.5.1.json"


def test_a_pin_catches_a_number_equal_to_another_leaf_of_its_file(
    checker: ModuleType, tmp_path: Path
) -> None:
    # the relit score written as the unrelit input's (11.21): a value of the same file, so the
    # section's declaration alone lets it through
    wrong = f"<!-- numbers-from: {DEMO} -->\n# x\n\nRelit, the example scores 11.21 dB.\n"
    assert checker.check_page(_page(tmp_path, wrong)) == []
    pin = "<!-- pin: 11.21 dB = " + DEMO + "#means.relit.object_raw.psnr -->"
    failures = checker.check_page(_page(tmp_path, wrong + pin + "\n"))
    assert len(failures) == 1
    assert ":4: 11.21 dB: pinned to" in failures[0] and "18.3669" in failures[0]
    # the right number passes its pin, at the end of the line or on the line above
    right = f"# x\n\nRelit, the example scores 18.37 dB. {pin.replace('11.21', '18.37')}\n"
    assert checker.check_page(_page(tmp_path, right)) == []
    above = f"# x\n\n{pin.replace('11.21', '18.37')}\nRelit, the example scores 18.37 dB.\n"
    assert checker.check_page(_page(tmp_path, above)) == []


def test_a_pin_covers_its_paragraph_only(checker: ModuleType, tmp_path: Path) -> None:
    pin = f"<!-- pin: 11.21 dB = {DEMO}#means.baselines.input.object_raw.psnr -->"
    page = _page(tmp_path, f"# x\n\n{pin}\nUnrelit: 11.21 dB.\n\nAgain 11.21 dB.\n")
    failures = checker.check_page(page)
    # the second paragraph has no pin and no declaration
    assert len(failures) == 1 and ":6: 11.21 dB: no numbers-from source" in failures[0]


def test_pins_name_real_leaves_and_numbers_of_their_paragraph(
    checker: ModuleType, tmp_path: Path
) -> None:
    missing = f"<!-- pin: 18.37 dB = {DEMO}#means.relit.object_raw.psnrr -->\nIt scores 18.37 dB.\n"
    failures = checker.check_page(_page(tmp_path, f"# x\n\n{missing}"))
    assert len(failures) == 1 and "no key 'psnrr'" in failures[0]
    no_file = f"<!-- pin: 18.37 dB = {R}/nope.json#a -->\nIt scores 18.37 dB.\n"
    failures = checker.check_page(_page(tmp_path, f"# x\n\n{no_file}"))
    assert len(failures) == 1 and "is not a JSON file" in failures[0]
    text_leaf = f"<!-- pin: 18.37 dB = {DEMO}#summary -->\nIt scores 18.37 dB.\n"
    failures = checker.check_page(_page(tmp_path, f"# x\n\n{text_leaf}"))
    assert len(failures) == 1 and "is not a number" in failures[0]
    # a pin whose number left its paragraph is stale
    stale = f"<!-- pin: 18.37 dB = {DEMO}#means.relit.object_raw.psnr -->\nIt scores well.\n"
    failures = checker.check_page(_page(tmp_path, f"# x\n\n{stale}"))
    assert len(failures) == 1 and "not a measured number of its paragraph" in failures[0]


def test_pins_of_differences_ratios_units_and_list_indexes(
    checker: ModuleType, tmp_path: Path
) -> None:
    test06 = f"{R}/reshade_render_test06.json"
    row = f"{test06}#rows.2"
    text = (
        f"<!-- pin: +3.91 dB = {row}.object_psnr_raw - #rows.2.input_object_psnr_raw; "
        f"88% = {row}.closer_than_input; 4.3 hours = {row}.train_seconds;\n"
        f"1.33x = {row}.object_psnr_raw / #rows.2.input_object_psnr_raw -->\n"
        "It gains +3.91 dB, wins on 88% of pairs, took 4.3 hours and scores 1.33x the input.\n"
    )
    assert checker.check_page(_page(tmp_path, f"# x\n\n{text}")) == []
    # the sign is part of the number: the same digits with the other sign fail
    flipped = text.replace("+3.91 dB =", "-3.91 dB =").replace("gains +3.91", "gains -3.91")
    failures = checker.check_page(_page(tmp_path, f"# x\n\n{flipped}"))
    assert len(failures) == 1 and "-3.91 dB: pinned to" in failures[0]


def test_a_unit_wrapped_onto_the_next_line_still_counts(
    checker: ModuleType, tmp_path: Path
) -> None:
    # "about 1.5\nminutes" once matched a load average of 1.53 (a bare decimal): with its unit it is
    # a time, and no time leaf of the file is 90 s
    src = tmp_path / "load.json"  # its own source: a measured file's values change when re-run
    src.write_text('{"load_average": 1.53, "seconds": 12.0}')
    text = f"<!-- numbers-from: {src} -->\n# x\n\nIt takes about 1.5\nminutes to run.\n"
    failures = checker.check_page(_page(tmp_path, text))
    assert len(failures) == 1 and ":4: 1.5 minutes: matches no value" in failures[0]
    # across a paragraph break the next line is not the number's
    apart = f"<!-- numbers-from: {src} -->\n# x\n\nA load of 1.5\n\nminutes later.\n"
    assert checker.check_page(_page(tmp_path, apart)) == []
