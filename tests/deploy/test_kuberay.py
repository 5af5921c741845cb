"""deploy/kuberay.yaml against the CRDs of a named KubeRay release (fixtures/kuberay/).

The API server validates a custom resource against its CRD version's openAPIV3Schema, and
`kubectl apply` (``--validate=strict``, its default) refuses fields the schema does not
name. Here that schema is checked with jsonschema, its Kubernetes extensions turned into
plain JSON Schema: an object with ``properties`` takes no other field unless it says
``x-kubernetes-preserve-unknown-fields``; ``x-kubernetes-int-or-string`` takes either.
The RayJob's ``rayClusterSpec`` also becomes a RayCluster (KubeRay creates one from it), so
it is checked against the RayCluster CRD too. The CRDs' CEL rules
(``x-kubernetes-validations``) are not evaluated: none concerns a field the manifest sets.
The operator's own checks that concern it (ray-operator/controllers/ray/utils/
validation.go) are repeated by hand below.
"""

from __future__ import annotations

import copy
import gzip
from collections.abc import Iterator
from functools import cache
from pathlib import Path
from typing import Any

import jsonschema
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
MANIFEST = ROOT / "deploy" / "kuberay.yaml"
CRDS = Path(__file__).resolve().parent / "fixtures" / "kuberay"
RELEASE = "v1.7.0"
"""The KubeRay release whose CRDs fixtures/kuberay/ holds (its README names the commit)."""


def _kubernetes_to_json_schema(node: Any) -> Any:
    """A CRD's structural schema as plain JSON Schema (draft 4, as OpenAPI 3.0 is)."""
    if isinstance(node, list):
        return [_kubernetes_to_json_schema(item) for item in node]
    if not isinstance(node, dict):
        return node
    out = {k: _kubernetes_to_json_schema(v) for k, v in node.items()}
    if out.pop("x-kubernetes-int-or-string", False):
        out.pop("type", None)
        out["anyOf"] = [{"type": "integer"}, {"type": "string"}]
    if out.pop("nullable", False) and "type" in out:
        out["type"] = [out["type"], "null"]
    preserve = out.pop("x-kubernetes-preserve-unknown-fields", False)
    if "properties" in out and not preserve:
        out.setdefault("additionalProperties", False)
    return out


@cache
def _crd(kind: str) -> dict[str, Any]:
    """The CRD of `kind` (plural, e.g. 'rayjobs'), parsed once (by libyaml: megabytes)."""
    with gzip.open(CRDS / f"ray.io_{kind}.yaml.gz", "rt") as f:
        return yaml.load(f, Loader=yaml.CSafeLoader)


@cache
def _validator(kind: str, version: str) -> jsonschema.Draft4Validator:
    """The validator of CRD `kind` at API version `version`."""
    crd = _crd(kind)
    (served,) = [v for v in crd["spec"]["versions"] if v["name"] == version and v["served"]]
    schema = _kubernetes_to_json_schema(served["schema"]["openAPIV3Schema"])
    jsonschema.Draft4Validator.check_schema(schema)
    return jsonschema.Draft4Validator(schema)


def _errors(kind: str, resource: dict[str, Any]) -> list[str]:
    """What the CRD's schema refuses in `resource`, one line each (its path, the reason)."""
    version = resource["apiVersion"].removeprefix("ray.io/")
    found = _validator(kind, version).iter_errors(resource)
    return sorted(f"{'.'.join(map(str, e.absolute_path))}: {e.message}" for e in found)


def _as_raycluster(job: dict[str, Any]) -> dict[str, Any]:
    """The RayCluster KubeRay creates for a RayJob."""
    return {
        "apiVersion": job["apiVersion"],
        "kind": "RayCluster",
        "metadata": {"name": job["metadata"]["name"]},
        "spec": job["spec"]["rayClusterSpec"],
    }


def _job() -> dict[str, Any]:
    (job,) = yaml.safe_load_all(MANIFEST.read_text())
    return job


def _groups(cluster_spec: dict[str, Any]) -> Iterator[tuple[str, dict[str, Any]]]:
    yield "head", cluster_spec["headGroupSpec"]
    for group in cluster_spec["workerGroupSpecs"]:
        yield group["groupName"], group


def test_the_fixtures_are_the_named_release():
    readme = (CRDS / "README.md").read_text()
    assert f"release **{RELEASE}**" in readme
    for kind in ("rayjobs", "rayclusters"):
        crd = _crd(kind)
        assert crd["spec"]["group"] == "ray.io" and crd["spec"]["names"]["plural"] == kind


def test_the_rayjob_validates_against_kuberays_crds():
    job = _job()
    assert (job["apiVersion"], job["kind"]) == ("ray.io/v1", "RayJob")
    assert _errors("rayjobs", job) == []
    assert _errors("rayclusters", _as_raycluster(job)) == []


def test_the_rayjob_passes_the_operators_own_checks():
    """validation.go's checks that concern the manifest: Ray labels in the group's
    ``labels`` field (``rayStartParams['labels']`` is refused), both replica bounds set
    without autoscaling, token auth only with Ray 2.52 or newer."""
    spec = _job()["spec"]["rayClusterSpec"]
    for name, group in _groups(spec):
        assert "labels" not in group.get("rayStartParams", {}), name
    for group in spec["workerGroupSpecs"]:
        assert group["minReplicas"] <= group["replicas"] <= group["maxReplicas"], group
    assert spec["authOptions"]["mode"] == "token"
    major, minor = map(int, spec["rayVersion"].split(".")[:2])
    assert (major, minor) >= (2, 52)


def _misspelt_field(job: dict[str, Any]) -> None:
    job["spec"]["rayClusterSpec"]["workerGroupSpecs"][0]["replica"] = 2


def _wrong_type(job: dict[str, Any]) -> None:
    job["spec"]["rayClusterSpec"]["workerGroupSpecs"][0]["replicas"] = "two"


def _misspelt_container_field(job: dict[str, Any]) -> None:
    head = job["spec"]["rayClusterSpec"]["headGroupSpec"]["template"]["spec"]
    head["containers"][0]["volumeMount"] = head["containers"][0].pop("volumeMounts", [])


def _unknown_auth_mode(job: dict[str, Any]) -> None:
    job["spec"]["rayClusterSpec"]["authOptions"]["mode"] = "password"


def _not_a_boolean(job: dict[str, Any]) -> None:
    job["spec"]["shutdownAfterJobFinishes"] = "yes"


@pytest.mark.parametrize(
    ("break_it", "refused"),
    [
        (_misspelt_field, "spec.rayClusterSpec.workerGroupSpecs.0: Additional properties"),
        (_wrong_type, "spec.rayClusterSpec.workerGroupSpecs.0.replicas: 'two' is not of type"),
        (_misspelt_container_field, "containers.0: Additional properties are not allowed"),
        (_unknown_auth_mode, "spec.rayClusterSpec.authOptions.mode: 'password' is not one of"),
        (_not_a_boolean, "spec.shutdownAfterJobFinishes: 'yes' is not of type 'boolean'"),
    ],
)
def test_a_broken_rayjob_is_refused_naming_the_field(break_it, refused):
    job = copy.deepcopy(_job())
    break_it(job)
    errors = _errors("rayjobs", job)
    assert any(refused in e for e in errors), errors
