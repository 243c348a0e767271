"""Human-readable report and JUnit XML."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections import Counter
from pathlib import Path

from .framework import CaseResult, Verdict

# what a verdict's "why" means, for the one-line reasons below a case
DETAILED = (Verdict.FAIL, Verdict.INFO)


def line(result: CaseResult) -> str:
    text = f"{result.verdict.value:<4}  {result.case.id:<34} {result.duration:6.3f}s  {result.case.title}"
    if result.verdict in (Verdict.SKIP, Verdict.INCONCLUSIVE):
        text += f"\n      why: {result.reason}"
    if result.verdict not in DETAILED:
        text += "".join(f"\n      note: {n}" for n in result.notes)
    return text


def details(result: CaseResult) -> list[str]:
    out = [f"      why:      {result.reason}"]
    if result.clause is not None:
        out.append(f"      clause:   {result.clause}")
    if result.expected is not None:
        out.append(f"      expected: {result.expected}")
    if result.seen is not None:
        out.append(f"      seen:     {result.seen}")
    out.extend(f"      note:     {n}" for n in result.notes)
    if result.frames:
        out.append("      frames (→ sent by the tester, ← seen on the bus):")
        out.extend(f"        {f}" for f in result.frames)
    return out


def summary(results: list[CaseResult]) -> str:
    counts = Counter(r.verdict for r in results)
    return (
        f"{len(results)} cases: {counts[Verdict.PASS]} passed, {counts[Verdict.FAIL]} failed,"
        f" {counts[Verdict.SKIP]} skipped, {counts[Verdict.INCONCLUSIVE]} inconclusive,"
        f" {counts[Verdict.INFO]} info"
    )


def text_report(results: list[CaseResult], header: str = "") -> str:
    out = [header] if header else []
    for r in results:
        out.append(line(r))
        if r.verdict in DETAILED:
            out.extend(details(r))
    out.append("")
    out.append(summary(results))
    return "\n".join(out) + "\n"


def junit_xml(
    results: list[CaseResult],
    suite_name: str = "fieldgate-conformance",
    properties: dict[str, str] | None = None,
) -> ET.ElementTree:
    counts = Counter(r.verdict for r in results)
    suites = ET.Element("testsuites")
    suite = ET.SubElement(
        suites,
        "testsuite",
        name=suite_name,
        tests=str(len(results)),
        failures=str(counts[Verdict.FAIL]),
        skipped=str(counts[Verdict.SKIP] + counts[Verdict.INCONCLUSIVE]),
        errors="0",
        time=f"{sum(r.duration for r in results):.3f}",
    )
    if properties:
        props = ET.SubElement(suite, "properties")
        for name, value in properties.items():
            ET.SubElement(props, "property", name=name, value=str(value))
    for r in results:
        tc = ET.SubElement(
            suite,
            "testcase",
            classname=f"conformance.{r.case.profile}",
            name=r.case.id,
            time=f"{r.duration:.3f}",
        )
        # JUnit knows pass, failure and skipped: INCONCLUSIVE is a skip whose message says so,
        # INFO a pass with the information in system-out; the verdict is a property of each
        ET.SubElement(ET.SubElement(tc, "properties"), "property", name="verdict", value=r.verdict)
        if r.verdict is Verdict.FAIL:
            failure = ET.SubElement(tc, "failure", message=r.reason)
            failure.text = "\n".join(details(r))
        elif r.verdict is Verdict.SKIP:
            ET.SubElement(tc, "skipped", message=r.reason)
        elif r.verdict is Verdict.INCONCLUSIVE:
            ET.SubElement(tc, "skipped", message=f"INCONCLUSIVE: {r.reason}")
        elif r.verdict is Verdict.INFO:
            ET.SubElement(tc, "system-out").text = "INFO\n" + "\n".join(details(r))
        elif r.notes:
            ET.SubElement(tc, "system-out").text = "\n".join(f"note: {n}" for n in r.notes)
    ET.indent(suites)
    return ET.ElementTree(suites)


def write_junit(
    results: list[CaseResult], path: str | Path, properties: dict[str, str] | None = None
) -> None:
    junit_xml(results, properties=properties).write(path, encoding="utf-8", xml_declaration=True)
