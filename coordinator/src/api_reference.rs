//! The API reference page of the book (`docs/api-reference.md`), rendered
//! from the OpenAPI document that the coordinator serves
//! ([`crate::openapi::document`]). It reads only the JSON document (paths,
//! operations, parameters, request bodies, responses, `components.schemas`
//! and the `x-irlgrid-role` of each operation), so it keeps working however
//! that document is produced. `coordinator/tests/api_reference.rs` fails
//! when the committed page differs from what this renders.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde_json::{Map, Value};

/// How to regenerate the page, as the page and the staleness test say it.
pub const REGENERATE: &str = "IRLGRID_BLESS=1 cargo test -p coordinator --test api_reference";

const METHODS: [&str; 5] = ["get", "post", "put", "patch", "delete"];

/// GitHub's (and mdBook's) heading anchor: lower case; letters, digits,
/// `-` and `_` kept; spaces become `-`; everything else dropped. The book's
/// link check (`tests/doc_anchors.rs`) resolves anchors with it too.
pub fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            '-' | '_' => Some(c),
            c if c.is_alphanumeric() => Some(c),
            _ => None,
        })
        .collect()
}

/// Text for one table cell: one line, `|` escaped.
fn cell(text: &str) -> String {
    text.split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .replace('|', "\\|")
}

fn str_of<'a>(v: &'a Value, key: &str) -> Option<&'a str> {
    v.get(key).and_then(Value::as_str)
}

/// The schema name a `$ref` to `#/components/schemas/<name>` names.
fn ref_name(v: &Value) -> Option<&str> {
    str_of(v, "$ref").and_then(|r| r.strip_prefix("#/components/schemas/"))
}

fn schema_link(name: &str) -> String {
    format!("[`{name}`](#{})", slug(name))
}

fn json_inline(v: &Value) -> String {
    match v {
        Value::String(s) => format!("`{s}`"),
        other => format!("`{other}`"),
    }
}

/// A schema's type in a few words, linking named schemas.
fn type_of(schema: &Value) -> String {
    if let Some(name) = ref_name(schema) {
        return schema_link(name);
    }
    if let Some(value) = schema.get("const") {
        return json_inline(value);
    }
    for (key, joiner) in [("oneOf", " or "), ("anyOf", " or "), ("allOf", " and ")] {
        if let Some(parts) = schema.get(key).and_then(Value::as_array) {
            // A derived enum with documented variants: one `const` each.
            let consts: Option<Vec<String>> = parts
                .iter()
                .map(|p| p.get("const").map(json_inline))
                .collect();
            if let Some(consts) = consts.filter(|c| c.len() > 1) {
                return format!("one of {}", consts.join(", "));
            }
            return parts.iter().map(type_of).collect::<Vec<_>>().join(joiner);
        }
    }
    if let Some(values) = schema.get("enum").and_then(Value::as_array) {
        let listed: Vec<String> = values.iter().map(json_inline).collect();
        return format!("one of {}", listed.join(", "));
    }
    let types: Vec<String> = match schema.get("type") {
        Some(Value::String(t)) => vec![t.clone()],
        Some(Value::Array(ts)) => ts
            .iter()
            .filter_map(Value::as_str)
            .map(str::to_string)
            .collect(),
        _ => Vec::new(),
    };
    let mut words: Vec<String> = types
        .iter()
        .map(|t| match t.as_str() {
            "array" => match schema.get("items") {
                Some(items) => format!("array of {}", type_of(items)),
                None => "array".to_string(),
            },
            "object" => match schema.get("additionalProperties") {
                Some(add) if add.is_object() => format!("map of {}", type_of(add)),
                _ => "object".to_string(),
            },
            other => other.to_string(),
        })
        .collect();
    if let Some(format) = str_of(schema, "format") {
        if let Some(first) = words.first_mut() {
            *first = format!("{first} ({format})");
        }
    }
    if words.is_empty() {
        "any".to_string()
    } else {
        words.join(" or ")
    }
}

/// The constraints JSON Schema states for one schema, e.g. `1 to 100`.
fn constraints(schema: &Value) -> String {
    let mut out = Vec::new();
    let num = |k: &str| {
        schema
            .get(k)
            .filter(|v| v.is_number())
            .map(Value::to_string)
    };
    let range = |lo: Option<String>, hi: Option<String>, what: &str| match (lo, hi) {
        (Some(lo), Some(hi)) => Some(format!("{what}{lo} to {hi}")),
        (Some(lo), None) => Some(format!("{what}at least {lo}")),
        (None, Some(hi)) => Some(format!("{what}at most {hi}")),
        (None, None) => None,
    };
    out.extend(range(num("minimum"), num("maximum"), ""));
    out.extend(range(num("minLength"), num("maxLength"), "length "));
    out.extend(range(num("minItems"), num("maxItems"), "items "));
    out.extend(range(
        num("minProperties"),
        num("maxProperties"),
        "entries ",
    ));
    if schema.get("uniqueItems") == Some(&Value::Bool(true)) {
        out.push("distinct items".to_string());
    }
    if let Some(names) = schema
        .get("propertyNames")
        .and_then(|p| p.get("enum"))
        .and_then(Value::as_array)
    {
        let listed: Vec<String> = names.iter().map(json_inline).collect();
        out.push(format!("keys: {}", listed.join(", ")));
    }
    if let Some(p) = str_of(schema, "pattern") {
        out.push(format!("pattern `{p}`"));
    }
    if let Some(d) = schema.get("default") {
        out.push(format!("default {}", json_inline(d)));
    }
    out.join("; ")
}

/// `content` of a request body or response: `type: schema` per media type.
fn content_of(v: &Value) -> String {
    let Some(content) = v.get("content").and_then(Value::as_object) else {
        return String::new();
    };
    content
        .iter()
        .map(|(media, m)| match m.get("schema") {
            Some(s) => format!("`{media}`: {}", type_of(s)),
            None => format!("`{media}`"),
        })
        .collect::<Vec<_>>()
        .join("; ")
}

fn sorted(map: Option<&Map<String, Value>>) -> BTreeMap<&str, &Value> {
    map.map(|m| m.iter().map(|(k, v)| (k.as_str(), v)).collect())
        .unwrap_or_default()
}

/// Every operation as (path, method, operation), paths in order, methods in
/// the order of [`METHODS`].
fn operations(doc: &Value) -> Vec<(&str, &'static str, &Value)> {
    let mut out = Vec::new();
    for (path, item) in sorted(doc.get("paths").and_then(Value::as_object)) {
        for method in METHODS {
            if let Some(op) = item.get(method) {
                out.push((path, method, op));
            }
        }
    }
    out
}

fn heading_of(path: &str, method: &str) -> String {
    format!("`{} {path}`", method.to_uppercase())
}

fn auth_of(op: &Value, doc: &Value) -> String {
    let security = op.get("security").or_else(|| doc.get("security"));
    match security.and_then(Value::as_array) {
        Some(reqs) if !reqs.is_empty() => {
            let schemes: Vec<String> = reqs
                .iter()
                .filter_map(Value::as_object)
                .flat_map(|r| r.keys().map(|k| format!("`{k}`")))
                .collect();
            format!("{} token", schemes.join(" or "))
        }
        _ => "none".to_string(),
    }
}

fn render_operation(out: &mut String, doc: &Value, path: &str, method: &str, op: &Value) {
    let _ = writeln!(out, "### {}\n", heading_of(path, method));
    if let Some(summary) = str_of(op, "summary") {
        let _ = writeln!(out, "{}\n", summary.trim());
    }
    if let Some(desc) = str_of(op, "description") {
        let _ = writeln!(out, "{}\n", desc.trim());
    }
    let role = str_of(op, "x-irlgrid-role").unwrap_or("-");
    let _ = writeln!(
        out,
        "Role: `{role}`. Authorization: {}.\n",
        auth_of(op, doc)
    );
    if let Some(params) = op.get("parameters").and_then(Value::as_array) {
        if !params.is_empty() {
            out.push_str("| parameter | in | required | type | description |\n");
            out.push_str("| --- | --- | --- | --- | --- |\n");
            for p in params {
                let schema = p.get("schema").cloned().unwrap_or(Value::Null);
                let mut desc = str_of(p, "description").unwrap_or("").to_string();
                let c = constraints(&schema);
                if !c.is_empty() {
                    desc = if desc.is_empty() {
                        c
                    } else {
                        format!("{desc}; {c}")
                    };
                }
                let _ = writeln!(
                    out,
                    "| `{}` | {} | {} | {} | {} |",
                    str_of(p, "name").unwrap_or("?"),
                    str_of(p, "in").unwrap_or("?"),
                    if p.get("required") == Some(&Value::Bool(true)) {
                        "yes"
                    } else {
                        "no"
                    },
                    cell(&type_of(&schema)),
                    cell(&desc)
                );
            }
            out.push('\n');
        }
    }
    if let Some(body) = op.get("requestBody") {
        let required = if body.get("required") == Some(&Value::Bool(true)) {
            "required"
        } else {
            "optional"
        };
        let _ = writeln!(out, "Request body ({required}): {}.\n", content_of(body));
    }
    let responses = sorted(op.get("responses").and_then(Value::as_object));
    if !responses.is_empty() {
        out.push_str("| status | meaning | body |\n| --- | --- | --- |\n");
        for (status, r) in responses {
            let _ = writeln!(
                out,
                "| {status} | {} | {} |",
                cell(str_of(r, "description").unwrap_or("")),
                cell(&content_of(r))
            );
        }
        out.push('\n');
    }
}

fn render_schema(out: &mut String, name: &str, schema: &Value) {
    let _ = writeln!(out, "### {name}\n");
    if let Some(desc) = str_of(schema, "description") {
        let _ = writeln!(out, "{}\n", desc.trim());
    }
    let props = sorted(schema.get("properties").and_then(Value::as_object));
    let variants: Vec<&Value> = schema
        .get("oneOf")
        .and_then(Value::as_array)
        .map(|v| v.iter().filter(|p| p.get("properties").is_some()).collect())
        .unwrap_or_default();
    if props.is_empty() && !variants.is_empty() {
        // A tagged enum: one table per variant.
        let _ = writeln!(out, "One of {} variants:\n", variants.len());
        for v in variants {
            render_fields(out, v, true);
        }
        return;
    }
    if props.is_empty() {
        let _ = writeln!(out, "Type: {}.\n", type_of(schema));
        let c = constraints(schema);
        if !c.is_empty() {
            let _ = writeln!(out, "Constraints: {c}.\n");
        }
        return;
    }
    render_fields(out, schema, false);
}

/// The field table of an object schema (led by its description for a
/// variant of a tagged enum).
fn render_fields(out: &mut String, schema: &Value, describe: bool) {
    let props = sorted(schema.get("properties").and_then(Value::as_object));
    if let Some(desc) = str_of(schema, "description").filter(|_| describe) {
        let _ = writeln!(out, "{}\n", desc.trim());
    }
    let required: Vec<&str> = schema
        .get("required")
        .and_then(Value::as_array)
        .map(|r| r.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    let mut notes = Vec::new();
    if let Some(t) = str_of(schema, "type").filter(|t| *t != "object") {
        notes.push(format!("type {t}"));
    }
    if schema.get("additionalProperties") == Some(&Value::Bool(false)) {
        notes.push("unknown fields are refused".to_string());
    }
    if !notes.is_empty() {
        let _ = writeln!(out, "An object; {}.\n", notes.join(", "));
    }
    out.push_str("| field | type | required | constraints | description |\n");
    out.push_str("| --- | --- | --- | --- | --- |\n");
    for (field, s) in props {
        let _ = writeln!(
            out,
            "| `{field}` | {} | {} | {} | {} |",
            cell(&type_of(s)),
            if required.contains(&field) {
                "yes"
            } else {
                "no"
            },
            cell(&constraints(s)),
            cell(str_of(s, "description").unwrap_or(""))
        );
    }
    out.push('\n');
}

/// The markdown page for an OpenAPI 3 document.
pub fn render(doc: &Value) -> String {
    let mut out = String::new();
    out.push_str("# API reference\n\n");
    let _ = writeln!(
        out,
        "<!-- Generated from the coordinator's OpenAPI document by \
         coordinator::api_reference; do not edit. Regenerate with: {REGENERATE} -->\n"
    );
    let title = doc
        .get("info")
        .and_then(|i| str_of(i, "title"))
        .unwrap_or("API");
    let openapi = str_of(doc, "openapi").unwrap_or("3");
    let _ = writeln!(
        out,
        "Every endpoint of the {title}, generated from the OpenAPI {openapi} \
         document it serves at `GET /api/v1/openapi.json`. Roles and tokens, \
         errors and the queue's guarantees are explained in \
         [The REST API](api.md).\n"
    );
    if let Some(desc) = doc.get("info").and_then(|i| str_of(i, "description")) {
        let _ = writeln!(out, "{}\n", desc.trim());
    }
    let ops = operations(doc);
    out.push_str("## Endpoints\n\n");
    out.push_str("| endpoint | role | summary |\n| --- | --- | --- |\n");
    for (path, method, op) in &ops {
        let heading = heading_of(path, method);
        let _ = writeln!(
            out,
            "| [{}](#{}) | {} | {} |",
            heading,
            slug(&heading),
            str_of(op, "x-irlgrid-role").unwrap_or("-"),
            cell(str_of(op, "summary").unwrap_or(""))
        );
    }
    out.push('\n');
    for (path, method, op) in &ops {
        render_operation(&mut out, doc, path, method, op);
    }
    let schemas = sorted(
        doc.get("components")
            .and_then(|c| c.get("schemas"))
            .and_then(Value::as_object),
    );
    if !schemas.is_empty() {
        out.push_str("## Schemas\n\n");
        for (name, schema) in schemas {
            render_schema(&mut out, name, schema);
        }
    }
    while out.ends_with("\n\n") {
        out.pop();
    }
    out
}

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    fn small() -> Value {
        json!({
            "openapi": "3.1.0",
            "info": {"title": "test service", "description": "A test."},
            "paths": {
                "/b/{id}": {"post": {
                    "summary": "make | break",
                    "x-irlgrid-role": "admin",
                    "security": [{"bearer": []}],
                    "parameters": [{"name": "id", "in": "path", "required": true,
                                    "schema": {"type": "integer", "minimum": 1}}],
                    "requestBody": {"required": true, "content": {"application/json":
                        {"schema": {"$ref": "#/components/schemas/Thing"}}}},
                    "responses": {"200": {"description": "made", "content": {"application/json":
                        {"schema": {"type": "array", "items": {"$ref": "#/components/schemas/Thing"}}}}},
                                  "409": {"description": "conflict"}}
                }},
                "/a": {"get": {"summary": "read", "x-irlgrid-role": "open",
                               "responses": {"204": {"description": "nothing"}}}}
            },
            "components": {"schemas": {
                "Thing": {"type": "object", "required": ["n"], "additionalProperties": false,
                          "properties": {"n": {"type": ["integer", "null"], "maximum": 9, "default": 3,
                                               "description": "a count"},
                                         "kind": {"enum": ["x", null]}}}
            }}
        })
    }

    #[test]
    fn renders_paths_operations_and_schemas() {
        let page = render(&small());
        for want in [
            "# API reference",
            REGENERATE,
            "| [`GET /a`](#get-a) | open | read |",
            "| [`POST /b/{id}`](#post-bid) | admin | make \\| break |",
            "### `POST /b/{id}`",
            "Role: `admin`. Authorization: `bearer` token.",
            "Role: `open`. Authorization: none.",
            "| `id` | path | yes | integer | at least 1 |",
            "Request body (required): `application/json`: [`Thing`](#thing).",
            "| 200 | made | `application/json`: array of [`Thing`](#thing) |",
            "| 409 | conflict |  |",
            "### Thing",
            "An object; unknown fields are refused.",
            "| `n` | integer or null | yes | at most 9; default `3` | a count |",
            "| `kind` | one of `x`, `null` | no |  |  |",
        ] {
            assert!(page.contains(want), "missing {want:?} in\n{page}");
        }
        // Paths in order, whatever order the document lists them in.
        assert!(page.find("### `GET /a`") < page.find("### `POST /b/{id}`"));
        assert!(!page.ends_with("\n\n") && page.ends_with('\n'));
    }

    #[test]
    fn every_link_of_the_real_page_names_one_of_its_headings() {
        let page = render(&crate::openapi::document());
        let headings: Vec<String> = page
            .lines()
            .filter_map(|l| l.strip_prefix("### "))
            .map(slug)
            .collect();
        let mut links = 0;
        for part in page.split("](#").skip(1) {
            let anchor: String = part.chars().take_while(|&c| c != ')').collect();
            assert!(headings.contains(&anchor), "no heading for #{anchor}");
            links += 1;
        }
        assert!(links > 40, "only {links} links");
        assert!(page.contains("### `POST /api/v1/leases`"));
        assert!(page.contains("### SearchRequest"));
    }
}
