"""The report page: written by every command that writes metrics.json, and checked in a real browser.

The browser is the distribution's headless Chromium driven by Selenium (no
download at run time); where it is not installed the browser test is skipped
with one line saying how to install it.
"""
import csv
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from pipelines.cli import main
from tests.browser import chromium
from vpr import report
from vpr.report import TABLE, settings, table_cells


def _run(argv, capsys):
    code = main([str(a) for a in argv] + ["--no-progress"])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def compared(scene_on_disk, tmp_path_factory):
    s = scene_on_disk("two_seasons", (64, 48), 120)
    out = tmp_path_factory.mktemp("report") / "run"
    assert main([str(a) for a in ["compare", s["summer_day"], s["winter_night"], "--out", out, "--gt", s["gt"],
                                  "--radius", 5, "--preset", "fast", "--no-progress"]]) == 0
    return out


def test_choose_shows_the_worst_first_within_the_limit():
    keys = np.array(["right"] * 50 + ["wrong"] * 5 + ["missed"] * 30 + ["lost"] * 10)
    score = np.r_[np.arange(50.0), 100 + np.arange(5.0), np.arange(30.0), np.arange(10.0)]
    shown, counts = report.choose(keys, score, 40)
    # shares of 40: wrong 14 (5 there: 9 go on), missed 10 + 9, lost 6, right 4; the 6 left to missed
    assert counts == {"wrong": (5, 5), "missed": (25, 30), "lost": (6, 10), "right": (4, 50)}
    assert list(keys[shown[:5]]) == ["wrong"] * 5 and score[shown[0]] == 104.0  # the most confident mistake first
    assert score[shown[-4]] == 0.0  # accepted and right: the closest call first
    assert report.outcome(True, 0, True) == "wrong" and report.outcome(False, 1, True) == "missed"
    assert report.outcome(True, None, None) == "accepted" and report.outcome(True, None, True) == "soft"


@pytest.mark.parametrize("sampling, said", [
    ({"speed": 1.87, "db_step": 2}, "moved 1.87 database frames a frame along the run's accepted paths, matched again "
                                    "against the database's 2 maps of one frame in 2"),
    ({"speed": 0.56, "query_step": 2}, "its frames matched as 2 queries of one frame in 2"),
    ({"speed": 1.9, "db_step": 2, "db_apart": 4}, "2 maps of one frame in 2, 4 frames they place apart left "
                                                  "undecided"),
    ({"db_step": 2, "db_step_frames": 60, "db_apart": 3},
     "60 frames answered by the map's 2 maps of one frame in 2 (3 placed apart by them, left undecided)"),
    ({"speed": 0.56, "query_step": 2, "query_filled": 7}, "queries of one frame in 2, 7 placed between the accepted "
                                                          "frames around them"),
    ({"query_step": 2, "query_step_frames": 50, "query_filled": 9},
     "50 frames answered as 2 queries of one frame in 2 (9 by the frame before)"),
    ({"db_step": 2, "db_step_frames": 91, "query_step": 2, "query_step_frames": 5},
     "91 frames answered by the map's 2 maps of one frame in 2; 5 frames answered as 2 queries of one frame in 2"),
    ({"sessions": [{"session": 2, "speed": 1.88, "db_step": 2}, {"session": 3, "speed": 1.0}]},
     "session 2 moved 1.88 of the earlier sessions' frames a frame, matched again against the earlier sessions' 2 "
     "maps of one frame in 2 (--query-speed follow)"),
    ({"sessions": [{"session": 2, "speed": 1.0}]}, None),
    ({"runs": [{"frames": [206, 299], "speed": 1.81, "db_step": 2, "db_apart": 0, "closures": 45}]},
     "frames 206-299 moved 1.81 earlier frames a frame, matched again against the frames before them as 2 maps of one "
     "frame in 2: 45 closures taken, confirmed by the frames after them (--query-speed follow)"),
    (None, None)])
def test_a_query_followed_at_another_speed_is_said_on_the_page(sampling, said):
    note = report.sampling_note("m", {"sampling": sampling} if sampling else {})
    assert (note is None) == (said is None) and (said is None or said in note), note
    if note and "sessions" in sampling:
        assert "session 3" not in note  # read at the earlier sessions' speed: nothing done, nothing said


@pytest.mark.slow  # a vpr compare run: command-line integration
def test_compare_writes_a_report_with_a_strip_per_decision_shown(compared):
    page = (compared / "report.html").read_text()
    metrics = json.loads((compared / "metrics.json").read_text())["methods"]
    for m, v in metrics.items():
        cells = table_cells(v, "match")
        row = page[page.index(f'<tr data-method="{m}">'):]
        assert all(f'data-key="{k}">{c}<' in row[:row.index("</tr>")] for (k, _), c in zip(TABLE["match"], cells,
                                                                                            strict=True))
    with open(compared / "rshosm-seq" / "matches.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {"right", "true_db", "true_name"} <= set(rows[0])  # matches.csv says which decisions are right
    wrong = [r for r in rows if r["accepted"] == "1" and r["right"] == "0"]
    for r in wrong[:5]:
        assert f'id="s-rshosm-seq-{r["query"]}"' in page
    assert (compared / "report.html").stat().st_size < 20e6


@pytest.mark.slow
def test_the_report_renders_in_a_real_browser(compared):
    from selenium.webdriver.common.by import By

    with chromium() as browser:
        browser.get((compared / "report.html").as_uri())
        errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
        assert not errors, errors
        metrics = json.loads((compared / "metrics.json").read_text())["methods"]
        for m, v in metrics.items():  # the table the browser shows is metrics.json's
            shown = [td.text for td in browser.find_elements(By.CSS_SELECTOR, f'tr[data-method="{m}"] td')[1:]]
            assert shown == table_cells(v, "match")
        strips = browser.find_elements(By.CSS_SELECTOR, ".strip")
        assert {s.get_attribute("data-method") for s in strips} == {m for m in metrics if "+" not in m}
        visible = browser.execute_script("return [...document.querySelectorAll('.strip')]"
                                         ".filter(s => s.offsetParent !== null).length")
        assert visible == len(strips)
        browser.find_element(By.CSS_SELECTOR, 'button[data-filter="outcome"][data-value="wrong"]').click()
        wrong = browser.execute_script("return [...document.querySelectorAll('.strip')]"
                                       ".filter(s => s.offsetParent !== null).length")
        assert 0 < wrong < visible
        assert browser.find_element(By.ID, "shown").text == f"{wrong} shown"
        loaded = browser.execute_script("return [...document.querySelectorAll('img')]"
                                        ".map(i => i.complete && i.naturalWidth > 0)")
        assert loaded and all(loaded)  # every thumbnail and plot is there
        # the run's settings, as metrics.json holds them (a run can be made again from its page)
        params = json.loads((compared / "metrics.json").read_text())["params"]
        shown = browser.execute_script("return Object.fromEntries([...document.querySelectorAll('#settings td')]"
                                       ".map(td => [td.dataset.key, td.textContent]))")
        assert shown == dict(settings(params)) and {"preset", "encoder", "method_conf", "ground_truth"} <= set(shown)
        assert json.loads(shown["ground_truth"]) == params["ground_truth"]
        _click_a_match_on_the_matrix(browser, "rshosm-seq", compared)


def _click_a_match_on_the_matrix(browser, method, folder):
    """A click on any cell of the method's similarity matrix shows that pair's frames: the database frame of the
    row and the query frame of the column (as the method's frames.json names them), with their captions."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    frames = json.loads((folder / method / "frames.json").read_text())
    img = browser.find_element(By.CSS_SELECTOR, f'img.matrix[data-method="{method}"]')
    x0, y0, x1, y1 = json.loads(img.get_attribute("data-box"))
    rows, cols = json.loads(img.get_attribute("data-shape"))
    assert (rows, cols) == (len(frames["rows"]), len(frames["columns"]))
    browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", img)
    w, h = img.size["width"], img.size["height"]
    for q, b in ((cols - 3, 2), (cols // 2, rows // 3)):  # any pair, not only the strips shown
        x = (x0 + (q + 0.5) / cols * (x1 - x0)) * w - w / 2  # from the picture's centre
        y = (y0 + (b + 0.5) / rows * (y1 - y0)) * h - h / 2
        ActionChains(browser).move_to_element_with_offset(img, round(x), round(y)).click().perform()
        box = img.find_element(By.XPATH, "..").find_element(By.CSS_SELECTOR, ".pair")
        r, c = int(box.get_attribute("data-row")), int(box.get_attribute("data-column"))
        assert abs(c - q) <= 1 and abs(r - b) <= 1  # a cell is a pixel or two: the one clicked or a neighbour
        shown = [f.find_element(By.TAG_NAME, "img").get_attribute("title") for f in
                 box.find_elements(By.TAG_NAME, "figure")]
        assert shown == [frames["columns"][c], frames["rows"][r]]  # every frame of this small run is embedded
        params = json.loads((folder / "metrics.json").read_text())["params"]
        srcs = [box.find_elements(By.TAG_NAME, "img")[k].get_attribute("src") for k in (0, 1)]
        for src, where, name in zip(srcs, (params["query"], params["db"]), shown, strict=True):
            # the query's own frame, not the database frame of the same file name
            assert src == report.thumbnail(cv2.imread(str(Path(where) / name)), 96, 60)
        assert all(browser.execute_script("return arguments[0].complete && arguments[0].naturalWidth > 0", i)
                   for i in box.find_elements(By.TAG_NAME, "img"))
        caps = [f.text for f in box.find_elements(By.TAG_NAME, "figcaption")]
        assert caps[0].startswith(f"query {c}: frame {c} · ") and caps[1].startswith(f"database {r}: frame {r} · ")
    button = img.find_element(By.XPATH, "..").find_element(By.CSS_SELECTOR, "button.full-size")
    button.click()
    assert "full" in img.get_attribute("class").split()  # the matrix at its full size


@pytest.mark.slow
def test_loops_and_localize_write_reports(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("loop_revisits", (48, 36), 240)
    code, _, err = _run(["loops", s["laps"], "--out", tmp_path / "loops", "--gt", s["gt"], "--radius", 4,
                         "--preset", "fast", "--exclude", 12, "--method-conf", "rshosm-seq.min_score=10"], capsys)
    assert code == 0, err
    page = (tmp_path / "loops" / "report.html").read_text()
    assert "closes onto" in page and 'class="strip right"' in page
    t = scene_on_disk("two_seasons", (64, 48), 120)
    code, _, err = _run(["localize", t["summer_day"], t["winter_night"], "--out", tmp_path / "loc", "--tolerance",
                         3], capsys)
    assert code == 0, err
    assert "ground truth --tolerance 3: 3 frames kept = 3 input frames; wrote" in err
    page = (tmp_path / "loc" / "report.html").read_text()
    assert 'data-method="rshosm-seq"' in page and "not read" not in page  # the map's frames found again
    assert f"vpr localize: {t['summer_day']} vs {t['winter_night']}" in page
    # an online run's page has the plot and the matrix of a batch run's
    assert 'alt="precision-recall"' in page and 'class="matrix"' in page
    assert (tmp_path / "loc" / "pr.png").is_file() and (tmp_path / "loc" / "rshosm-seq" / "similarity.png").is_file()


@pytest.mark.slow  # a vpr compare run: command-line integration
def test_a_rejected_best_match_in_the_soft_band_is_neither_and_the_counts_parse(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (64, 48), 120)
    out = tmp_path / "soft"
    code, _, err = _run(["compare", s["summer_day"], s["winter_night"], "--out", out, "--gt", s["gt"], "--radius", 5,
                         "--gt-soft", 15, "--preset", "fast", "--methods", "pairwise"], capsys)
    assert code == 0, err
    with open(out / "pairwise" / "matches.csv") as fh:
        rows = list(csv.DictReader(fh))
    soft = sum(r["right"] == "" and int(r["best_db"]) >= 0 for r in rows)
    lost = sum(r["accepted"] == "0" and r["right"] == "0" for r in rows)
    assert soft > 0
    page = (out / "report.html").read_text()
    text = page[page.index('<script type="application/json" id="counts">'):]
    counts = json.loads(text[text.index(">") + 1:text.index("</script>")])  # as JSON.parse reads it
    assert counts["pairwise"].get("soft", [0, 0])[1] == soft  # accepted or not, neither right nor wrong
    assert counts["pairwise"].get("lost", [0, 0])[1] == lost


@pytest.mark.slow  # a vpr compare run: command-line integration
def test_without_ground_truth_a_strip_is_query_and_best_match_by_score(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (64, 48), 120)
    out = tmp_path / "nogt"
    code, _, err = _run(["compare", s["summer_day"], s["winter_night"], "--out", out, "--preset", "fast",
                         "--methods", "pairwise"], capsys)
    assert code == 0, err
    page = (out / "report.html").read_text()
    assert "true match" not in page and "not read" not in page
    assert "no ground truth" in page and "worst first</h2>" not in page
    strip = page[page.index('<div class="strip'):]
    assert strip[:strip.index("</div>")].count("<figure") == 2  # query | best match


@pytest.mark.slow
def test_the_verified_variant_has_its_link_strips_and_filter(scene_on_disk, tmp_path, capsys):
    s = scene_on_disk("two_seasons", (64, 48), 120)
    out = tmp_path / "v"
    code, _, err = _run(["compare", s["summer_day"], s["winter_night"], "--out", out, "--gt", s["gt"], "--radius", 5,
                         "--preset", "fast", "--methods", "pairwise", "--verify", 2], capsys)
    assert code == 0, err
    with open(out / "pairwise" / "matches.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert {"verified_name", "verified_right"} <= set(rows[0])
    page = (out / "report.html").read_text()
    assert '<a href="#strips" data-method="pairwise+verify">' in page
    assert 'class="strip' in page and 'data-method="pairwise+verify" data-outcome=' in page
    assert 'data-filter="method" data-value="pairwise+verify"' in page
