//! Every answer the service tests receive is checked against the server's own OpenAPI document
//! (`GET /api/openapi.json`): its status must be one the document lists for the route and
//! method, and a JSON body must match the schema documented for that status. Requests to paths
//! the document does not describe (unknown routes, the dashboard's pages) are not checked.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};

use serde_json::{Value, json};

/// The document of each server, by base URL (fetched once).
static DOCS: Mutex<Option<HashMap<String, Arc<Value>>>> = Mutex::new(None);

fn document(base: &str) -> Arc<Value> {
    let mut docs = DOCS.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    let docs = docs.get_or_insert_with(HashMap::new);
    if let Some(d) = docs.get(base) {
        return d.clone();
    }
    let text = ureq::get(&format!("{base}/api/openapi.json"))
        .call()
        .unwrap_or_else(|e| panic!("{base}/api/openapi.json: {e}"))
        .into_string()
        .unwrap();
    let doc: Arc<Value> = Arc::new(serde_json::from_str(&text).unwrap());
    docs.insert(base.to_string(), doc.clone());
    doc
}

/// Forgets the document of the server at `base` (it stopped; another may get its port).
pub fn forget(base: &str) {
    let mut docs = DOCS.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
    if let Some(docs) = docs.as_mut() {
        docs.remove(base);
    }
}

/// The documented path template `path` (no query) matches, if any: `{name}` stands for one segment.
fn template<'d>(doc: &'d Value, path: &str) -> Option<&'d str> {
    let segments: Vec<&str> = path.split('/').collect();
    doc["paths"].as_object()?.keys().map(String::as_str).find(|t| {
        let parts: Vec<&str> = t.split('/').collect();
        parts.len() == segments.len()
            && parts
                .iter()
                .zip(&segments)
                .all(|(p, s)| (p.starts_with('{') && p.ends_with('}') && !s.is_empty()) || p == s)
    })
}

/// Checks an answer of `status` with `body` (and its `content_type`) to `method url` against
/// the document of the server at `base`; panics with what disagrees.
pub fn check(base: &str, method: &str, url: &str, status: u16, content_type: Option<&str>, body: &str) {
    let Some(rest) = url.strip_prefix(base) else {
        return;
    };
    let path = rest.split('?').next().unwrap_or_default();
    let doc = document(base);
    let Some(t) = template(&doc, path) else {
        return;
    };
    let Some(op) = doc["paths"][t].get(method.to_lowercase()) else {
        // A method the route does not take: the framework's 405.
        assert_eq!(status, 405, "{method} {t}: not documented, answered {status}: {body}");
        return;
    };
    let response = &op["responses"][status.to_string()];
    assert!(
        response.is_object(),
        "{method} {t} answered {status}, which its OpenAPI document does not list ({:?}): {}",
        op["responses"].as_object().map(|r| r.keys().collect::<Vec<_>>()),
        &body[..body.len().min(500)]
    );
    let json_body = content_type.is_some_and(|c| c.starts_with("application/json"));
    let Some(schema) = response["content"]["application/json"].get("schema") else {
        assert!(
            !json_body || response["content"].as_object().is_none_or(|c| c.is_empty()),
            "{method} {t} {status}: JSON answered where the document says {:?}",
            response["content"]
        );
        return;
    };
    assert!(
        json_body,
        "{method} {t} {status}: documented as JSON, answered {content_type:?}: {body}"
    );
    let instance: Value =
        serde_json::from_str(body).unwrap_or_else(|e| panic!("{method} {t} {status}: not JSON ({e}): {body}"));
    let errors = schema_errors(&doc["components"], schema, &instance)
        .unwrap_or_else(|e| panic!("{method} {t} {status}: bad schema: {e}"));
    assert!(
        errors.is_empty(),
        "{method} {t} {status}: the answer does not match its documented schema: {errors:#?}\n{}",
        &body[..body.len().min(1000)]
    );
}

/// What in `instance` disagrees with `schema` (JSON Schema 2020-12), whose `$ref`s point into the
/// OpenAPI document's `components`; empty when it matches. An error when the schema itself is bad.
fn schema_errors(components: &Value, schema: &Value, instance: &Value) -> Result<Vec<String>, Box<boon::CompileError>> {
    let root = json!({
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "components": components,
        "allOf": [schema],
    });
    let mut compiler = boon::Compiler::new();
    let mut schemas = boon::Schemas::new();
    compiler.add_resource("urn:stylet:openapi", root).map_err(Box::new)?;
    let schema = compiler.compile("urn:stylet:openapi", &mut schemas).map_err(Box::new)?;
    Ok(match schemas.validate(instance, schema) {
        Ok(()) => Vec::new(),
        Err(e) => leaf_errors(&e),
    })
}

/// Every innermost cause of a validation error, each with where in the answer it is.
fn leaf_errors(e: &boon::ValidationError) -> Vec<String> {
    if e.causes.is_empty() {
        vec![format!("{} at {}", e.kind, e.instance_location)]
    } else {
        e.causes.iter().flat_map(leaf_errors).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn components() -> Value {
        json!({"schemas": {"Session": {
            "type": "object",
            "required": ["id", "score"],
            "properties": {"id": {"type": "string"}, "score": {"type": ["number", "null"]}}
        }}})
    }

    #[test]
    fn an_answer_matching_its_referenced_schema_passes() {
        let schema = json!({"type": "array", "items": {"$ref": "#/components/schemas/Session"}});
        let answer = json!([{"id": "a", "score": 81.5}, {"id": "b", "score": null}]);
        assert_eq!(
            schema_errors(&components(), &schema, &answer).unwrap(),
            Vec::<String>::new()
        );
    }

    #[test]
    fn each_disagreement_is_named_with_where_it_is() {
        let schema = json!({"type": "array", "items": {"$ref": "#/components/schemas/Session"}});
        let answer = json!([{"id": "a", "score": "high"}, {"score": 3}]);
        let errors = schema_errors(&components(), &schema, &answer).unwrap();
        assert_eq!(errors.len(), 2, "{errors:#?}");
        assert!(errors[0].ends_with("at /0/score"), "{errors:#?}");
        assert!(errors[1].contains("id") && errors[1].ends_with("at /1"), "{errors:#?}");
    }

    #[test]
    fn a_reference_to_a_missing_schema_is_a_bad_schema() {
        let schema = json!({"$ref": "#/components/schemas/Missing"});
        assert!(schema_errors(&components(), &schema, &json!({})).is_err());
    }
}
