"""schemathesis against the service's OpenAPI schema over real HTTP: no input makes it answer 5xx,
and every answer matches the published schema (status codes, content types, bodies)."""

from __future__ import annotations

import io
from collections.abc import Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.errors import Unsatisfiable
from schemathesis import GenerationMode
from schemathesis.specs.openapi.checks import (
    content_type_conformance,
    ignored_auth,
    response_schema_conformance,
    status_code_conformance,
    unsupported_method,
)
from server_fixtures import API_TOKEN, RunningService, follow_events

from calib.io.readers import write_native_csv
from calib.simulator import simulate

HEADERS = {"Authorization": f"Bearer {API_TOKEN}"}


@pytest.fixture(scope="module")
def api(tmp_path_factory: pytest.TempPathFactory) -> Iterator[RunningService]:
    db = tmp_path_factory.mktemp("schema") / "store.sqlite3"
    svc = RunningService(["--mock", "2", "--mock-speed", "10"], f"sqlite:///{db}").start()
    yield svc
    svc.stop()


@pytest.fixture(scope="module")
def known_ids(api: RunningService) -> dict[str, str]:
    """Real ids for the fuzzer to hit besides random ones: an uploaded and a live session."""
    rec, _ = simulate(4)
    buf = io.StringIO()
    write_native_csv(rec, buf)
    with api.client() as c:
        upload = c.post("/devices/upload-1/calibrate", content=buf.getvalue(), headers={"Content-Type": "text/csv"}).json()
        live = c.post("/devices/mock-2/calibrate", json={}).json()
    follow_events(api.base, live["session_id"], {"done", "failed", "cancelled"}, timeout_s=60, last_event_id=0)
    return {"upload": upload["session_id"], "live": live["session_id"]}


def not_a_server_error(ctx: schemathesis.CheckContext, response: schemathesis.Response, case: schemathesis.Case) -> None:
    if response.status_code >= 500:
        raise AssertionError(f"{case.method} {case.formatted_path} answered {response.status_code}: {response.text[:500]}")


# not negative_data_rejection: every case carries the operator's real token over whatever Authorization it drew,
# so a "negative" header is never what the service sees (wrong types in the body are tested in test_server_limits)
CHECKS = (not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance, ignored_auth,
          unsupported_method)


def test_no_input_makes_the_service_fail(api: RunningService, known_ids: dict[str, str]) -> None:
    """Every operation, with generated valid and invalid inputs, random and real ids, an operator's token."""
    schema = schemathesis.openapi.from_url(f"{api.base}/openapi.json")
    failures: list[str] = []
    labels = []
    for result in schema.get_all_operations():
        op = result.ok()
        labels.append(op.label)
        if op.label == "GET /fleet/events":
            continue  # an endless stream by design, nothing to generate for it: tests/server/test_fleet_events.py
        # the event stream of a session held in memory stays open for its accept/discard events:
        # only the stored (uploaded) one is a finite stream
        sessions = [known_ids["upload"]] if op.label.endswith("/events") else list(known_ids.values())
        for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE):

            @settings(max_examples=4, deadline=None, suppress_health_check=list(HealthCheck), database=None)
            @given(case=op.as_strategy(generation_mode=mode), device=st.sampled_from([None, "mock-1", "upload-1"]),
                   session=st.sampled_from([None, *sessions]))
            def run(case: schemathesis.Case, device: str | None, session: str | None) -> None:
                params = case.path_parameters or {}
                if device and "device_id" in params:
                    params["device_id"] = device
                if session and "session_id" in params:
                    params["session_id"] = session
                case.call_and_validate(headers=HEADERS, checks=CHECKS, timeout=15)

            try:
                run()
            except Unsatisfiable:
                assert mode is GenerationMode.NEGATIVE  # an operation without inputs has no invalid ones
            except Exception as exc:  # collect every operation's failure, then report them all
                failures.append(f"{op.label} ({mode.value}): {type(exc).__name__}: {str(exc)[:1500]}")
    assert "POST /devices/{device_id}/calibrate" in labels and "GET /sessions/{session_id}/events" in labels
    assert "GET /fleet/events" in labels
    assert not failures, "\n\n".join(failures)
    with api.client() as c:
        assert c.get("/health").json()["status"] == "ok"


def test_a_result_is_a_typed_object_in_the_published_schema(api: RunningService) -> None:
    """The session's result, an upload's result and an accepted calibration are calib.result_schema's models, with
    their fields, in the OpenAPI document (not free objects)."""
    import httpx

    doc = httpx.get(f"{api.base}/openapi.json", timeout=10, verify=False).json()
    parts = doc["components"]["schemas"]

    def target(prop: dict) -> str:
        refs = [p.get("$ref") for p in prop.get("anyOf", [prop])]
        return next(r for r in refs if r).rsplit("/", 1)[1]

    assert target(parts["SessionOut"]["properties"]["result"]) == "ResultDoc"
    assert target(parts["SessionOut"]["properties"]["checks"]["items"]) == "Check"
    assert target(parts["SessionOut"]["properties"]["departures"]["items"]) == "Departure"
    result = parts["ResultDoc"]["properties"]
    assert {"k", "b", "K", "G", "uncertainty", "stages", "quality", "residuals", "format_version"} <= set(result)
    assert target(result["quality"]) == "Quality" and "protocol" in parts["Quality"]["properties"]
    assert {"k", "b", "quality", "recording_sha256", "checks"} <= set(parts["OfflineResult"]["properties"])
    record = parts["CalibrationRecord"]["properties"]
    assert target(record["quality"]) == "Quality" and target(record["uncertainty"]) == "Spread"


# The API's only free-form maps: what each one holds depends on the device, the audited action, the effect or the
# estimator that wrote it (docs/service.md). Every other object an answer carries is typed, field by field.
FREE_FORM = {
    "DeviceDetail.info",  # what the wearable said about itself: each model tells different things
    "AuditEntry.detail",  # what each audited action records
    "Effect.parameters", "Effect.uncertainty", "Effect.evidence",  # each physical effect has its own parameters
    "DiagnosisInfo.timebase",  # how the time base was read: depends on the clock the recording carries
    "Quality.ferraris", "Quality.g_sensitivity", "Quality.settling", "Quality.accelerometer_floor",
    "Quality.gyro_motion_noise", "Quality.constraint_fit",  # one estimator's own diagnostic blocks
}


def free_form_maps(doc: dict) -> set[str]:
    """Every object without declared fields that a 2xx JSON answer of ``doc`` can carry, as Component.field."""
    parts = doc["components"]["schemas"]
    found: set[str] = set()
    seen: set[str] = set()

    def walk(schema: dict, where: str) -> None:
        if "$ref" in schema:
            name = schema["$ref"].rsplit("/", 1)[1]
            if name not in seen:
                seen.add(name)
                walk(parts[name], name)
            return
        for key in ("anyOf", "oneOf", "allOf"):
            for sub in schema.get(key, []):
                walk(sub, where)
        if "items" in schema:
            walk(schema["items"], where)
        extra = schema.get("additionalProperties")
        if schema.get("type") == "object" and "properties" not in schema and extra in (None, True, {}):
            found.add(where)
        if isinstance(extra, dict):
            walk(extra, where)
        for field, sub in schema.get("properties", {}).items():
            walk(sub, f"{where.split('.')[0]}.{field}")

    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            for code, answer in op.get("responses", {}).items():
                body = answer.get("content", {}).get("application/json")
                if code.startswith("2") and body is not None:
                    assert body.get("schema"), f"{method.upper()} {path} {code} publishes no schema"
                    walk(body["schema"], f"{method.upper()} {path}")
    return found


def test_every_answer_is_typed_but_the_documented_free_form_maps(api: RunningService) -> None:
    """A session's snapshot (live reading, turns, warnings), a device, the fleet, a verification, a plot: each a typed
    object in the OpenAPI document, down to the free-form maps listed above."""
    import httpx

    doc = httpx.get(f"{api.base}/openapi.json", timeout=10, verify=False).json()
    assert free_form_maps(doc) == FREE_FORM
    parts = doc["components"]["schemas"]
    snapshot = parts["SessionOut"]["properties"]
    assert snapshot["live"]["anyOf"][0]["$ref"].endswith("/LiveOut")
    assert snapshot["warnings"]["items"]["$ref"].endswith("/SessionWarning")
    assert snapshot["turns"]["additionalProperties"]["$ref"].endswith("/TurnOut")
    assert parts["SessionOut"].get("additionalProperties") is False  # nothing a snapshot carries goes undeclared
