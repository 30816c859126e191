#!/usr/bin/env python3
"""Consistency checks of the Kubernetes manifests in deploy/k8s (no cluster).

    check_manifests.py [DIR]        checks DIR (default deploy/k8s); exit 1
                                    and one "FAIL: ..." line per problem
    check_manifests.py --self-test  breaks the manifests in known ways and
                                    checks that each break is reported

What refers to what, and must agree:
  * every Service selects the pods of a workload, and its targetPort is a
    containerPort of theirs (by name or number);
  * a StatefulSet's serviceName is a Service; selectors match pod labels;
  * every volumeMount is a pod volume or a volumeClaimTemplate;
  * every Secret a pod uses (volume or secretKeyRef) is defined, with the
    key asked for;
  * IRLGRID_TOKEN_FILE and IRLGRID_WORKER_TOKEN_FILE are files of a mounted
    Secret volume;
  * workers get the worker token only (IRLGRID_WORKER_TOKEN_FILE), never the
    admin token (IRLGRID_TOKEN, IRLGRID_TOKEN_FILE);
  * the workers' IRLGRID_COORDINATOR is http://<Service>:<its port>;
  * the coordinator's IRLGRID_DB lies on its PersistentVolumeClaim;
  * every IRLGRID_* variable is one the irlgrid binary reads (src/cli);
  * every container sets CPU and memory requests and limits;
  * the coordinator has readiness and liveness probes: GET /healthz on its
    container port;
  * a worker's IRLGRID_SHUTDOWN_GRACE is below its pod's
    terminationGracePeriodSeconds;
  * autoscalers target the worker Deployment and use a metric the
    coordinator serves (coordinator/src/metrics.rs).

Needs PyYAML.
"""

import copy
import glob
import os
import re
import sys
from urllib.parse import urlparse

import yaml

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))


def load(directory):
    docs = []
    for path in sorted(glob.glob(os.path.join(directory, "*.yaml"))):
        with open(path) as f:
            for d in yaml.safe_load_all(f):
                if d:
                    d["__file__"] = os.path.basename(path)
                    docs.append(d)
    return docs


def known_env_vars():
    names = set()
    for path in glob.glob(os.path.join(ROOT, "src", "cli", "*.rs")):
        with open(path) as f:
            names.update(re.findall(r'env\s*=\s*"(IRLGRID_[A-Z0-9_]+)"', f.read()))
    # Read by the binary outside clap (tracing set-up).
    names.add("IRLGRID_LOG_JSON")
    return names


def served_metrics():
    with open(os.path.join(ROOT, "coordinator", "src", "metrics.rs")) as f:
        return set(re.findall(r'"(irlgrid_[a-z_]+)', f.read()))


def pod_spec(d):
    if d.get("kind") in ("Deployment", "StatefulSet", "DaemonSet", "Job"):
        return d.get("spec", {}).get("template", {}).get("spec", {})
    return None


def pod_labels(d):
    return d.get("spec", {}).get("template", {}).get("metadata", {}).get("labels", {}) or {}


def env_map(c):
    return {e.get("name"): e for e in c.get("env", []) or []}


def name_of(d):
    return f'{d.get("kind")}/{d.get("metadata", {}).get("name")} ({d.get("__file__")})'


def check(docs, env_known=None, metrics=None):
    env_known = known_env_vars() if env_known is None else env_known
    metrics = served_metrics() if metrics is None else metrics
    errors = []
    err = errors.append

    for d in docs:
        for k in ("apiVersion", "kind"):
            if not d.get(k):
                err(f"{name_of(d)}: no {k}")
        if not d.get("metadata", {}).get("name"):
            err(f"{name_of(d)}: no metadata.name")

    by_kind = {}
    for d in docs:
        by_kind.setdefault(d.get("kind"), {})[d.get("metadata", {}).get("name")] = d
    services = by_kind.get("Service", {})
    secrets = by_kind.get("Secret", {})
    workloads = [d for d in docs if pod_spec(d) is not None]

    def secret_keys(name):
        s = secrets.get(name)
        if s is None:
            return None
        return set((s.get("data") or {}).keys()) | set((s.get("stringData") or {}).keys())

    # Services select pods and target one of their ports.
    for sname, svc in services.items():
        sel = svc.get("spec", {}).get("selector") or {}
        chosen = [w for w in workloads if sel and sel.items() <= pod_labels(w).items()]
        if not chosen:
            err(f"{name_of(svc)}: selector {sel} matches no pod template")
        ports = set()
        for w in chosen:
            for c in pod_spec(w).get("containers", []):
                for p in c.get("ports", []) or []:
                    ports.add(p.get("containerPort"))
                    if p.get("name"):
                        ports.add(p["name"])
        for p in svc.get("spec", {}).get("ports", []) or []:
            target = p.get("targetPort", p.get("port"))
            if chosen and target not in ports:
                err(f"{name_of(svc)}: targetPort {target!r} is no containerPort of the selected pods {sorted(map(str, ports))}")

    for w in workloads:
        spec = w.get("spec", {})
        ps = pod_spec(w)
        labels = pod_labels(w)
        match = (spec.get("selector") or {}).get("matchLabels") or {}
        if not match or not match.items() <= labels.items():
            err(f"{name_of(w)}: selector {match} does not match the pod labels {labels}")
        if w.get("kind") == "StatefulSet":
            if spec.get("serviceName") not in services:
                err(f"{name_of(w)}: serviceName {spec.get('serviceName')!r} is no Service")
            if not spec.get("volumeClaimTemplates"):
                err(f"{name_of(w)}: no volumeClaimTemplates (the database needs a PersistentVolumeClaim)")
        claims = {t.get("metadata", {}).get("name") for t in spec.get("volumeClaimTemplates", []) or []}
        volumes = {v.get("name"): v for v in ps.get("volumes", []) or []}
        grace = ps.get("terminationGracePeriodSeconds", 30)

        # Secrets the pod mounts exist and have the keys asked for.
        for v in volumes.values():
            sec = v.get("secret")
            if not sec:
                continue
            keys = secret_keys(sec.get("secretName"))
            if keys is None:
                err(f"{name_of(w)}: volume {v['name']} uses Secret {sec.get('secretName')!r}, which is not defined")
                continue
            for item in sec.get("items", []) or []:
                if item.get("key") not in keys:
                    err(f"{name_of(w)}: volume {v['name']} asks for key {item.get('key')!r} of Secret {sec.get('secretName')}, which has {sorted(keys)}")

        for c in ps.get("containers", []) or []:
            cname = f"{name_of(w)} container {c.get('name')}"
            res = c.get("resources") or {}
            for part in ("requests", "limits"):
                for r in ("cpu", "memory"):
                    if not (res.get(part) or {}).get(r):
                        err(f"{cname}: no resources.{part}.{r}")
            mounts = {}
            for m in c.get("volumeMounts", []) or []:
                if m.get("name") not in volumes and m.get("name") not in claims:
                    err(f"{cname}: volumeMount {m.get('name')!r} is no volume or claim template")
                mounts[m.get("name")] = m.get("mountPath", "")
            env = env_map(c)
            for n, e in env.items():
                if n and n.startswith("IRLGRID_") and n not in env_known:
                    err(f"{cname}: env {n} is not read by irlgrid")
                ref = (e.get("valueFrom") or {}).get("secretKeyRef")
                if ref:
                    keys = secret_keys(ref.get("name"))
                    if keys is None or ref.get("key") not in keys:
                        err(f"{cname}: env {n} refers to key {ref.get('key')!r} of Secret {ref.get('name')!r}, not defined")
            if "IRLGRID_TOKEN" in env and "valueFrom" not in env["IRLGRID_TOKEN"]:
                err(f"{cname}: IRLGRID_TOKEN is a literal value; use a Secret")

            # A worker holds the worker token only.
            if c.get("args", [None])[0] == "worker":
                for admin in ("IRLGRID_TOKEN", "IRLGRID_TOKEN_FILE"):
                    if admin in env:
                        err(f"{cname}: a worker gets the admin token ({admin}); give it IRLGRID_WORKER_TOKEN_FILE")
                if "IRLGRID_WORKER_TOKEN_FILE" not in env and "IRLGRID_WORKER_TOKEN" not in env:
                    err(f"{cname}: a worker without IRLGRID_WORKER_TOKEN_FILE")

            # A token file is a file of a mounted Secret volume.
            for tf_var in ("IRLGRID_TOKEN_FILE", "IRLGRID_WORKER_TOKEN_FILE"):
                tf = (env.get(tf_var) or {}).get("value")
                if tf is not None:
                    found = False
                    for vname, path in mounts.items():
                        v = volumes.get(vname) or {}
                        sec = v.get("secret")
                        if not sec or not tf.startswith(path.rstrip("/") + "/"):
                            continue
                        rel = tf[len(path.rstrip("/")) + 1:]
                        items = sec.get("items")
                        files = {i.get("path") for i in items} if items else (secret_keys(sec.get("secretName")) or set())
                        found = found or rel in files
                    if not found:
                        err(f"{cname}: {tf_var}={tf} is no file of a mounted Secret volume")

            db = (env.get("IRLGRID_DB") or {}).get("value")
            if db is not None and not any(
                n in claims and db.startswith(p.rstrip("/") + "/") for n, p in mounts.items()
            ):
                err(f"{cname}: IRLGRID_DB={db} is not on a PersistentVolumeClaim mount")

            url = (env.get("IRLGRID_COORDINATOR") or {}).get("value")
            if url is not None:
                u = urlparse(url)
                svc = services.get(u.hostname)
                if svc is None:
                    err(f"{cname}: IRLGRID_COORDINATOR={url}: host {u.hostname!r} is no Service")
                elif u.port not in {p.get("port") for p in svc["spec"].get("ports", [])}:
                    err(f"{cname}: IRLGRID_COORDINATOR={url}: port {u.port} is not a port of Service {u.hostname}")

            g = (env.get("IRLGRID_SHUTDOWN_GRACE") or {}).get("value")
            if g is not None and not int(g) < int(grace):
                err(f"{cname}: IRLGRID_SHUTDOWN_GRACE={g} is not below terminationGracePeriodSeconds={grace}")

            if c.get("args", [None])[0] == "coordinator":
                names = {p.get("name") for p in c.get("ports", []) or []}
                numbers = {p.get("containerPort") for p in c.get("ports", []) or []}
                bind = (env.get("IRLGRID_BIND") or {}).get("value", "")
                if bind and int(bind.rsplit(":", 1)[1]) not in numbers:
                    err(f"{cname}: IRLGRID_BIND={bind} is not on a containerPort {sorted(numbers)}")
                for probe in ("readinessProbe", "livenessProbe"):
                    hg = (c.get(probe) or {}).get("httpGet")
                    if not hg:
                        err(f"{cname}: no {probe} (httpGet)")
                        continue
                    if hg.get("path") != "/healthz":
                        err(f"{cname}: {probe} path {hg.get('path')!r}, want /healthz")
                    if hg.get("port") not in names | numbers:
                        err(f"{cname}: {probe} port {hg.get('port')!r} is not the container port")

    # Autoscalers scale the worker Deployment on a served metric.
    deployments = by_kind.get("Deployment", {})
    for kind in ("HorizontalPodAutoscaler", "ScaledObject"):
        for d in by_kind.get(kind, {}).values():
            ref = d.get("spec", {}).get("scaleTargetRef") or {}
            if ref.get("name") not in deployments or ref.get("kind", "Deployment") != "Deployment":
                err(f"{name_of(d)}: scaleTargetRef {ref} is no Deployment")
            text = yaml.safe_dump(d.get("spec", {}).get("metrics", []) or d.get("spec", {}).get("triggers", []))
            used = set(re.findall(r"irlgrid_[a-z_]+", text))
            # An adapter may rename a series: irlgrid_jobs_open is
            # sum(irlgrid_jobs{state=~"queued|leased"}) (hpa.yaml gives the rule).
            unknown = {m for m in used if m not in metrics and not any(m.startswith(s + "_") for s in metrics)}
            if not used or unknown:
                err(f"{name_of(d)}: metric(s) {sorted(unknown) or 'none'} not served by the coordinator")
    return errors


def find(docs, kind, name):
    return next(d for d in docs if d.get("kind") == kind and d["metadata"]["name"] == name)


def container(docs, kind, name):
    return pod_spec(find(docs, kind, name))["containers"][0]


def set_env(c, name, value):
    for e in c["env"]:
        if e["name"] == name:
            e["value"] = value
            return
    raise KeyError(name)


# (what it breaks, how, a phrase the report must contain)
BREAKS = [
    ("Service targetPort", lambda d: find(d, "Service", "irlgrid-coordinator")["spec"]["ports"][0].update(targetPort="web"),
     "targetPort 'web'"),
    ("Secret key", lambda d: find(d, "Secret", "irlgrid-token")["stringData"].update({"tokn": "x"}) or
     find(d, "Secret", "irlgrid-token")["stringData"].pop("token"), "asks for key 'token'"),
    ("Secret name", lambda d: pod_spec(find(d, "Deployment", "irlgrid-worker"))["volumes"][1]["secret"].update(secretName="irlgrid-tokens"),
     "'irlgrid-tokens', which is not defined"),
    ("coordinator URL", lambda d: set_env(container(d, "Deployment", "irlgrid-worker"), "IRLGRID_COORDINATOR", "http://coordinator:8080"),
     "host 'coordinator' is no Service"),
    ("coordinator port", lambda d: set_env(container(d, "Deployment", "irlgrid-worker"), "IRLGRID_COORDINATOR", "http://irlgrid-coordinator:80"),
     "port 80 is not a port"),
    ("token file path", lambda d: set_env(container(d, "Deployment", "irlgrid-worker"), "IRLGRID_WORKER_TOKEN_FILE", "/run/secrets/token"),
     "is no file of a mounted Secret"),
    ("admin token to a worker", lambda d: container(d, "Deployment", "irlgrid-worker")["env"].append(
        {"name": "IRLGRID_TOKEN_FILE", "value": "/run/secrets/irlgrid/worker-token"}),
     "a worker gets the admin token (IRLGRID_TOKEN_FILE)"),
    ("worker limits", lambda d: container(d, "Deployment", "irlgrid-worker")["resources"].pop("limits"),
     "no resources.limits.cpu"),
    ("probe path", lambda d: container(d, "StatefulSet", "irlgrid-coordinator")["readinessProbe"]["httpGet"].update(path="/health"),
     "path '/health'"),
    ("probe port", lambda d: container(d, "StatefulSet", "irlgrid-coordinator")["livenessProbe"]["httpGet"].update(port=9090),
     "livenessProbe port 9090"),
    ("unknown env", lambda d: container(d, "Deployment", "irlgrid-worker")["env"].append({"name": "IRLGRID_TOKN", "value": "x"}),
     "IRLGRID_TOKN is not read"),
    ("grace", lambda d: set_env(container(d, "Deployment", "irlgrid-worker"), "IRLGRID_SHUTDOWN_GRACE", "30"),
     "not below terminationGracePeriodSeconds"),
    ("database off the claim", lambda d: set_env(container(d, "StatefulSet", "irlgrid-coordinator"), "IRLGRID_DB", "/tmp/irlgrid.db"),
     "not on a PersistentVolumeClaim"),
    ("serviceName", lambda d: find(d, "StatefulSet", "irlgrid-coordinator")["spec"].update(serviceName="irlgrid"),
     "serviceName 'irlgrid'"),
    ("autoscaler target", lambda d: find(d, "HorizontalPodAutoscaler", "irlgrid-worker")["spec"]["scaleTargetRef"].update(name="worker"),
     "is no Deployment"),
    ("autoscaler metric", lambda d: find(d, "ScaledObject", "irlgrid-worker")["spec"]["triggers"][0]["metadata"].update(query="sum(irlgrid_queue)"),
     "irlgrid_queue"),
]


def self_test(directory):
    docs = load(directory)
    base = check(docs)
    if base:
        print("\n".join("FAIL: " + e for e in base))
        return 1
    missed = 0
    for what, brk, phrase in BREAKS:
        broken = copy.deepcopy(docs)
        brk(broken)
        errs = check(broken)
        hit = [e for e in errs if phrase in e]
        if hit:
            print(f"PASS: broken {what} reported: {hit[0]}")
        else:
            missed += 1
            print(f"FAIL: broken {what} not reported (want {phrase!r}; got {errs})")
    return 1 if missed else 0


def main(argv):
    if len(argv) > 1 and argv[1] == "--self-test":
        return self_test(argv[2] if len(argv) > 2 else os.path.join(ROOT, "deploy", "k8s"))
    directory = argv[1] if len(argv) > 1 else os.path.join(ROOT, "deploy", "k8s")
    docs = load(directory)
    if not docs:
        print(f"FAIL: no manifests in {directory}")
        return 1
    errors = check(docs)
    for e in errors:
        print("FAIL: " + e)
    if not errors:
        kinds = sorted(f"{d['kind']}/{d['metadata']['name']}" for d in docs)
        print(f"PASS: {len(docs)} manifests consistent: {', '.join(kinds)}")
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
