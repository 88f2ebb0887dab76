"""A check's result as JUnit XML (``minirt check --junit``): per scene a testsuite, per backend and
check a testcase, failed, in error or skipped as its verdict says.
"""

from __future__ import annotations

from minirt.harness.results import Check, CheckResult


def junit_xml(result: CheckResult) -> str:
    import xml.etree.ElementTree as ET

    root = ET.Element("testsuites", name="minirt check")
    for s in result.scenes:
        suite = ET.SubElement(root, "testsuite", name=s.scene, file=s.file)
        n = {"tests": 0, "failures": 0, "errors": 0, "skipped": 0}
        for b in s.backends.values():
            checks = b.checks or {"render": Check(b.verdict, reason=b.reason)}
            for cname, c in checks.items():
                case = ET.SubElement(
                    suite, "testcase", classname=f"{s.scene}.{b.backend}", name=cname, time=f"{b.seconds:.3f}"
                )
                n["tests"] += 1
                if c.verdict == "fail":
                    ET.SubElement(case, "failure", message=c.reason or "fail")
                    n["failures"] += 1
                elif c.verdict == "error":
                    ET.SubElement(case, "error", message=c.reason or "error")
                    n["errors"] += 1
                elif c.verdict == "skip":
                    ET.SubElement(case, "skipped", message=c.reason or "skip")
                    n["skipped"] += 1
        for k, v in n.items():
            suite.set(k, str(v))
    return ET.tostring(root, encoding="unicode", xml_declaration=True)
