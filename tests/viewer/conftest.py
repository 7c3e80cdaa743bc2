"""One line in the test log saying whether the viewer's browser tests ran in Chromium (CI's evidence)."""


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    counts = {}
    for key in ("passed", "failed", "error", "skipped"):
        for rep in terminalreporter.stats.get(key, []):
            if "tests/viewer/test_browser.py" in getattr(rep, "nodeid", "") and rep.when in ("call", "setup"):
                if key == "passed" and rep.when != "call":
                    continue
                counts[key] = counts.get(key, 0) + 1
    if counts:
        from dyngi.viewer.browser import find_chromium

        parts = ", ".join(f"{n} {k}" for k, n in counts.items())
        terminalreporter.write_line(f"viewer browser tests (headless {find_chromium() or 'no chromium'}): {parts}")
