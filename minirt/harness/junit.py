"""A check's result as JUnit XML (``minirt check --junit``): per scene a testsuite, per backend and
check a testcase, failed, in error or skipped as its verdict says.

Every text from a scene file or a renderer (a scene's name, a reason) goes through
minirt.io.untrusted.xml_text: the control characters XML 1.0 forbids are written as visible ``\\x1b``-style
escapes, so the file stays XML whatever a scene is named.
"""

from __future__ import annotations

from minirt.harness.results import Check, CheckResult
from minirt.io.untrusted import xml_text as x


def junit_xml(result: CheckResult) -> str:
    import xml.etree.ElementTree as ET

    root = ET.Element("testsuites", name="minirt check")
    for s in result.scenes:
        suite = ET.SubElement(root, "testsuite", name=x(s.scene), file=x(s.file))
        n = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
        for b in s.backends.values():
            checks = b.checks or {"render": Check(b.verdict, reason=b.reason)}
            for cname, c in checks.items():
                case = ET.SubElement(
                    suite, "testcase", classname=x(f"{s.scene}.{b.backend}"), name=x(cname), time=f"{b.seconds:.3f}"
                )
                n["tests"] += 1
                if c.verdict == "fail":
                    ET.SubElement(case, "failure", message=x(c.reason or "fail"))
                    n["failures"] += 1
                elif c.verdict == "error":
                    ET.SubElement(case, "error", message=x(c.reason or "error"))
                    n["errors"] += 1
                elif c.verdict == "skip":
                    ET.SubElement(case, "skipped", message=x(c.reason or "skip"))
                    n["skipped"] += 1
        for k, v in n.items():
            suite.set(k, str(v))
    # Written as UTF-8 (minirt.io.atomic.write_text), whatever the locale: the declaration says so.
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"
