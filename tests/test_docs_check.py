"""make docs-check: every number in README.md and docs/**/*.md is generated from, or checked against,
a recording in docs/figures/ (tools/docs_check.py); and the checker itself catches what it must."""

import json
import os
import sys

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, "tools"))

import docs_check as DC
import figures as F


def test_docs_agree_with_their_recordings():
    """The CI hook: the README and the docs pages (docs/**/*.md) against docs/figures/ (fast: nothing is re-run)."""
    problems = []
    for f in DC.default_files():
        p, _ = DC.check_file(f)
        problems += p
    assert not problems, "\n".join(str(p) for p in problems[:40]) + f"\n({len(problems)} problems; make docs-check)"


def test_every_recording_names_its_command_and_commit():
    names = [n[:-5] for n in os.listdir(DC.FIG_DIR) if n.endswith(".json")]
    assert "demo" in names
    for n in names:
        rec = DC.recording(n)
        assert DC.check_recording(n, rec) is None, n
        if not n.startswith("cited_"):
            assert n in F.SOURCES, f"{n}: recorded, but no source in tools/figures.py says which command makes it"
            assert rec["command"].split()[0] in ("python", "make"), rec["command"]


def test_cited_paper_numbers_are_the_ones_the_code_prints():
    from clothfit.core import defaults as D

    d = DC.recording("cited_paper")["data"]
    assert [D.PAPER_TABLE1[c] for c in d["table1"]["cameras"]] == list(
        zip(d["table1"]["silhouette_pct"], d["table1"]["shape_mm"])
    )
    for res, row in D.PAPER_TABLE2.items():
        assert [row[c] for c in d["table2"]["cameras"]] == d["table2"][f"{res[0]}x{res[1]}"]


def test_readme_pictures_are_the_recorded_demo_runs():
    """docs/img copies of the demo's pictures are byte for byte the pictures of the recorded run; the
    README shows one of them, the docs pages (demo, add-on) the others."""
    pics = DC.recording("demo")["data"]["story"]["pictures"]
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        readme = f.read()
    pages = ""
    for path in DC.default_files()[1:]:
        with open(path, encoding="utf-8") as f:
            pages += f.read()
    assert any(f"docs/img/{n}" in readme for n in pics), "the README shows a picture of the demo"
    shown = [n for n in pics if f"](img/{n})" in pages]
    assert len(shown) >= 3, "the docs pages show the demo's pictures"
    for n in pics:
        p = os.path.join(ROOT, "docs", "img", n)
        if os.path.isfile(p):
            assert F._sha256(p) == pics[n], f"docs/img/{n} is not the recorded demo run's picture: make docs-images"


# ------------------------------------------------------------------ the checker catches what it must


@pytest.fixture
def fake(tmp_path, monkeypatch):
    figs = tmp_path / "figures"
    figs.mkdir()
    rec = {
        "format": F.FORMAT,
        "version": 1,
        "name": "t",
        "command": "python x.py",
        "commit": "abc1234",
        "dirty": False,
        "recorded_at": "2025-01-01T00:00:00Z",
        "data": {
            "err_pct": 0.0812,
            "rows": [{"material": "silk (soft)", "mm": 1.234}, {"material": "denim", "mm": 2.5}],
            "s": 31.2,
            "a": 52.0,
            "b": 3.3,
            "xs": [1.0, 2.5, 0.3],
        },
    }
    (figs / "t.json").write_text(json.dumps(rec))
    (figs / "cited_p.json").write_text(json.dumps({"citation": "a paper", "data": {"x": [6.243]}}))
    monkeypatch.setattr(DC, "FIG_DIR", str(figs))
    monkeypatch.setattr(DC, "_RECORDINGS", {})

    def check(md):
        p = tmp_path / "doc.md"
        p.write_text(md)
        problems, stats = DC.check_file(str(p))
        return [x.msg for x in problems], stats

    return check


def test_a_tagged_figure_within_its_rounding_passes(fake):
    msgs, stats = fake("The fit recovers k/m within 0.08 %<!--fig t err_pct-->.\n")
    assert msgs == [] and stats["figures"] == 1


def test_a_figure_that_differs_from_its_recording_fails(fake):
    msgs, _ = fake("The fit recovers k/m within 0.03 %<!--fig t err_pct-->.\n")
    assert len(msgs) == 1 and "differs from the recorded err_pct" in msgs[0]


def test_more_digits_than_the_recording_supports_fail(fake):
    assert fake("within 0.0813 %<!--fig t err_pct-->\n")[0]
    assert not fake("within 0.0812 %<!--fig t err_pct-->\n")[0]


def test_a_stated_tolerance_is_honoured(fake):
    assert fake("about 30 s<!--fig t s-->\n")[0]
    assert not fake("about 30 s<!--fig t s~5%-->\n")[0]
    assert not fake("16x faster<!--fig t {a}/{b}~1%-->\n")[0]
    assert not fake("worst 2.5 mm<!--fig t {max(xs)}-->\n")[0]
    assert not fake("1.23 to 2.5 mm<!--fig t {min(rows.*.mm)} {max(rows.*[material^=de].mm)}-->\n")[0]


def test_an_untagged_number_fails_and_inputs_do_not(fake):
    msgs, _ = fake("A fit takes 31.2 s on this machine.\n")
    assert len(msgs) == 1 and "has no tag" in msgs[0]
    assert not fake("A 10 cm sheet, 5 % noise<!--in-->, took 31.2 s<!--fig t s-->.\n")[0]


def test_a_tag_covers_only_its_own_numbers(fake):
    msgs, _ = fake("A 10 cm sheet took 31.2 s<!--fig t s-->.\n")
    assert len(msgs) == 1 and "10" in msgs[0]


def test_references_versions_sizes_and_code_are_not_figures(fake):
    md = (
        "Blender 4.5.15 and Python 3.11 (Figure 3, Table 1, section 6.2, eq. 6) on a 2-core machine, "
        "480 x 640 images of cam05 and lab18, `--budget 2500`, [link](docs/a1.md).\n\n"
        "```\npython -m clothfit fit --max-evaluations 1500\n```\n"
    )
    msgs, _ = fake(md)
    assert msgs == []


def test_an_inputs_region_accepts_untagged_numbers_and_still_checks_tags(fake):
    assert not fake("<!--inputs: options-->\n`--budget` at least 1, at most 16384 per side.\n<!--/inputs-->\n")[0]
    msgs, _ = fake("<!--inputs: options-->\nit took 30 s<!--fig t s-->\n<!--/inputs-->\nand 5 more\n")
    assert len(msgs) == 2 and "differs" in msgs[0] and "has no tag" in msgs[1]
    assert "has no <!--/inputs-->" in fake("<!--inputs-->\n5\n")[0][0]


def test_a_measurement_in_a_code_comment_fails(fake):
    msgs, _ = fake("```\npython tools/x.py   # 14 min\n```\n")
    assert len(msgs) == 1 and "code comment" in msgs[0]


def test_list_selection_and_skips(fake):
    assert not fake(
        "silk 1.23 mm, denim 2.5 mm at 3 mm<!--fig t rows[material^=silk].mm rows[material=denim].mm _-->\n"
    )[0]
    msgs, _ = fake("silk 1.3 mm<!--fig t rows[material^=silk].mm-->\n")
    assert msgs and "differs" in msgs[0]


def test_unknown_keys_and_recordings_fail(fake):
    assert "key" in fake("0.08 %<!--fig t nope-->\n")[0][0]
    assert "no recording" in fake("0.08 %<!--fig nothere x-->\n")[0][0]


def test_citations_are_checked_and_kept_apart(fake):
    assert not fake("the paper's 6.243 %<!--cite cited_p x.0-->\n")[0]
    assert fake("the paper's 6.25 %<!--cite cited_p x.0-->\n")[0]
    assert "'cite' is for citations" in fake("6.243<!--fig cited_p x.0-->\n")[0][0]


def test_generated_blocks_must_equal_their_rendering(fake, monkeypatch):
    import docs_views

    monkeypatch.setitem(docs_views.VIEWS, "t.err", lambda rec: f"| err | {rec('t')['data']['err_pct']:.2f} |")
    assert not fake("<!--gen t.err-->\n| err | 0.08 |\n<!--/gen-->\n")[0]
    msgs, _ = fake("<!--gen t.err-->\n| err | 0.07 |\n<!--/gen-->\n")
    assert msgs and "differs from its rendering" in msgs[0]


def test_rerun_comparison_ignores_timings_and_flags_figures():
    old = {"rows": [{"mean_mm": 0.5, "wall_s": 10.0}], "evals_per_s": 60.0, "n": 3}
    assert F.compare(old, {"rows": [{"mean_mm": 0.5, "wall_s": 99.0}], "evals_per_s": 20.0, "n": 3}) == []
    assert F.compare(old, {"rows": [{"mean_mm": 0.6, "wall_s": 10.0}], "evals_per_s": 60.0, "n": 3})
    assert (
        F.compare(old, {"rows": [{"mean_mm": 0.5000001, "wall_s": 10.0}], "evals_per_s": 60.0, "n": 3}, rtol=1e-6) == []
    )
