//! The OpenAPI 3.1 document of the JSON API (`GET /api/openapi.json`), written by hand next to the
//! routes it describes (tests check that every route is in it).

use serde_json::{Value, json};

fn error_response(description: &str) -> Value {
    json!({ "description": description, "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Error" } } } })
}

pub fn document() -> Value {
    json!({
        "openapi": "3.1.0",
        "info": {
            "title": "Stylet scoring service",
            "version": env!("CARGO_PKG_VERSION"),
            "description": "Uploads of session files, scoring by deterministic replay, scores by role. See docs/api.md."
        },
        "components": {
            "securitySchemes": {
                "cookie": { "type": "apiKey", "in": "cookie", "name": "stylet_session",
                            "description": "From POST /api/login. State-changing requests also send X-CSRF-Token." },
                "token": { "type": "http", "scheme": "bearer", "description": "From POST /api/tokens. Scope `upload` (the desktop simulator): POST /api/sessions, GET /api/sessions/{id} and GET /api/sessions/{id}/file only, 403 elsewhere; scope `full`: the account's rights. Expired or revoked: 401." }
            },
            "schemas": {
                "Error": { "type": "object", "required": ["error"], "properties": { "error": { "type": "string" } } },
                "Role": { "type": "string", "enum": ["trainee", "instructor", "curriculum", "admin"] },
                "Account": {
                    "type": "object",
                    "required": ["username", "role", "cohorts", "created_at"],
                    "properties": {
                        "username": { "type": "string" }, "role": { "$ref": "#/components/schemas/Role" },
                        "cohorts": { "type": "array", "items": { "type": "string" } },
                        "created_at": { "type": "string" },
                        "disabled_at": { "type": ["string", "null"], "description": "when it was disabled; null: active" }
                    }
                },
                "ImportRefused": {
                    "type": "object", "required": ["error", "lines"],
                    "properties": {
                        "error": { "type": "string" },
                        "lines": { "type": "array", "items": { "type": "object", "required": ["line", "reason"],
                                   "properties": { "line": { "type": "integer", "description": "1 = the first line; 0 = the whole file" },
                                                   "reason": { "type": "string" } } } }
                    }
                },
                "ApiToken": {
                    "type": "object",
                    "required": ["id", "username", "label", "scope", "created_at", "status"],
                    "properties": {
                        "id": { "type": "string" }, "username": { "type": "string" }, "label": { "type": "string" },
                        "scope": { "type": "string", "enum": ["upload", "full"] },
                        "created_at": { "type": "string" }, "expires_at": { "type": ["string", "null"] },
                        "revoked_at": { "type": ["string", "null"] },
                        "last4": { "type": ["string", "null"], "description": "The token's last four hex digits" },
                        "status": { "type": "string", "enum": ["active", "expired", "revoked"] }
                    }
                },
                "Session": {
                    "type": "object",
                    "required": ["id", "trainee", "scenario", "difficulty", "status", "uploaded_at", "duration_s"],
                    "properties": {
                        "id": { "type": "string" }, "trainee": { "type": "string" }, "scenario": { "type": "string" },
                        "difficulty": { "type": "string", "enum": ["beginner", "advanced", "expert"] },
                        "status": { "type": "string", "enum": ["queued", "scoring", "scored", "failed"] },
                        "uploaded_at": { "type": "string" }, "duration_s": { "type": "number" },
                        "error": { "type": ["string", "null"] },
                        "score": { "description": "The score report of docs/metrics.md once scored, else null" }
                    }
                }
            }
        },
        "paths": {
            "/healthz": { "get": { "summary": "Health: the database and the data directory can be written", "responses": { "200": { "description": "{\"status\":\"ok\"}" }, "503": error_response("the database or the data directory cannot be written") } } },
            "/api/openapi.json": { "get": { "summary": "This document", "responses": { "200": { "description": "OpenAPI 3.1" } } } },
            "/api/login": { "post": {
                "summary": "Log in; sets the stylet_session cookie",
                "requestBody": { "required": true, "content": { "application/json": { "schema": {
                    "type": "object", "required": ["username", "password"],
                    "properties": { "username": { "type": "string" }, "password": { "type": "string" } } } } } },
                "responses": {
                    "200": { "description": "{username, role, csrf_token}" },
                    "400": error_response("malformed body"),
                    "403": error_response("sent from another site (Sec-Fetch-Site, or an Origin or Referer that is not this server)"),
                    "401": error_response("wrong username or password"),
                    "429": error_response("too many failed logins for this account")
                }
            } },
            "/api/logout": { "post": { "summary": "Log out", "responses": { "200": { "description": "logged out" } } } },
            "/api/users": {
                "get": {
                    "summary": "Accounts with role, cohorts and status, by username, 100 a page (admin)",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "parameters": [
                        { "name": "q", "in": "query", "schema": { "type": "string" }, "description": "part of a username" },
                        { "name": "page", "in": "query", "schema": { "type": "integer", "minimum": 1, "default": 1 } }
                    ],
                    "responses": { "200": { "description": "{users: [Account], total, page, page_size}" },
                                   "401": error_response("not logged in, or the account is disabled"), "403": error_response("not an admin") }
                },
                "post": {
                    "summary": "Add an account, or import accounts from CSV (admin; audited)",
                    "description": "JSON adds one account. `Content-Type: text/csv` imports one account per line, `username,role,cohort,password` (optional header line; cohort may be empty; the password is the rest of the line; at most 200 lines): every account or none; 422 names every bad line.",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "requestBody": { "required": true, "content": {
                        "application/json": { "schema": {
                            "type": "object", "required": ["username", "role", "password"], "additionalProperties": false,
                            "properties": { "username": { "type": "string" },
                                            "role": { "$ref": "#/components/schemas/Role" },
                                            "password": { "type": "string", "minLength": 8 },
                                            "cohort": { "type": "string" } } } },
                        "text/csv": { "schema": { "type": "string" } } } },
                    "responses": { "201": { "description": "{username, role, cohort}; for a CSV import {imported: [usernames]}" },
                                   "400": error_response("invalid username, role, password or cohort"),
                                   "401": error_response("not logged in"), "403": error_response("not an admin, or CSRF token missing"),
                                   "409": error_response("the username exists"),
                                   "422": { "description": "an import with bad lines; nothing was imported",
                                            "content": { "application/json": { "schema": { "$ref": "#/components/schemas/ImportRefused" } } } } }
                }
            },
            "/api/users/{username}": {
                "get": {
                    "summary": "One account (admin)",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "parameters": [{ "name": "username", "in": "path", "required": true, "schema": { "type": "string" } }],
                    "responses": { "200": { "description": "Account", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Account" } } } },
                                   "401": error_response("not logged in"), "403": error_response("not an admin"),
                                   "404": error_response("no such account") }
                },
                "patch": {
                    "summary": "Change an account's role, cohorts or status (admin; audited per change)",
                    "description": "`cohorts` replaces the account's cohorts (created if new; [] for none). Takes effect on the account's next request.",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "parameters": [{ "name": "username", "in": "path", "required": true, "schema": { "type": "string" } }],
                    "requestBody": { "required": true, "content": { "application/json": { "schema": {
                        "type": "object", "additionalProperties": false,
                        "properties": { "role": { "$ref": "#/components/schemas/Role" },
                                        "cohorts": { "type": "array", "items": { "type": "string" } },
                                        "disabled": { "type": "boolean" } } } } } },
                    "responses": { "200": { "description": "Account", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Account" } } } },
                                   "400": error_response("bad role or cohort name"),
                                   "401": error_response("not logged in"), "403": error_response("not an admin, or CSRF token missing"),
                                   "404": error_response("no such account"),
                                   "409": error_response("it would leave no active admin, or an admin disabling or demoting their own account") }
                }
            },
            "/api/users/{username}/disable": { "post": {
                "summary": "Disable an account (admin; audited): its login cookies and API tokens are refused from the next request; its sessions stay",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "username", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": { "200": { "description": "Account", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Account" } } } },
                               "401": error_response("not logged in"), "403": error_response("not an admin, or CSRF token missing"),
                               "404": error_response("no such account"),
                               "409": error_response("the last active admin, or one's own account") }
            } },
            "/api/users/{username}/enable": { "post": {
                "summary": "Enable a disabled account (admin; audited): its unexpired logins and tokens work again",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "username", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": { "200": { "description": "Account", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Account" } } } },
                               "401": error_response("not logged in"), "403": error_response("not an admin, or CSRF token missing"),
                               "404": error_response("no such account") }
            } },
            "/api/users/{username}/password": { "post": {
                "summary": "Reset an account's password (admin; audited); its logins end",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "username", "in": "path", "required": true, "schema": { "type": "string" } }],
                "requestBody": { "required": true, "content": { "application/json": { "schema": {
                    "type": "object", "required": ["password"], "additionalProperties": false,
                    "properties": { "password": { "type": "string", "minLength": 8, "maxLength": 1024 } } } } } },
                "responses": { "200": { "description": "Account", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Account" } } } },
                               "400": error_response("a password has 8–1024 characters"),
                               "401": error_response("not logged in"), "403": error_response("not an admin, or CSRF token missing"),
                               "404": error_response("no such account") }
            } },
            "/api/tokens": {
                "post": {
                    "summary": "Create an API token for the logged-in user (shown once; audited)",
                    "description": "Login cookie and X-CSRF-Token only: a request authenticated by an API token gets 403. Scope `upload` (default) may only upload sessions and read their status; `full` has the account's rights.",
                    "security": [{ "cookie": [] }],
                    "requestBody": { "required": true, "content": { "application/json": { "schema": {
                        "type": "object", "required": ["label"], "additionalProperties": false,
                        "properties": { "label": { "type": "string", "minLength": 1, "maxLength": 100 },
                                        "scope": { "type": "string", "enum": ["upload", "full"], "default": "upload" },
                                        "expires_in_days": { "type": "integer", "minimum": 1, "maximum": 90, "default": 90 } } } } } },
                    "responses": { "201": { "description": "ApiToken and `token`, the secret, shown only here" },
                                   "400": error_response("bad label, scope or expiry"),
                                   "401": error_response("not logged in"),
                                   "403": error_response("CSRF token missing, or authenticated by an API token") }
                },
                "get": {
                    "summary": "The caller's API tokens (an admin's: everyone's), newest first, never the secret",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "responses": { "200": { "description": "{tokens: [ApiToken]}", "content": { "application/json": { "schema": {
                                       "type": "object", "properties": { "tokens": { "type": "array", "items": { "$ref": "#/components/schemas/ApiToken" } } } } } } },
                                   "401": error_response("not logged in, or the token expired or was revoked"),
                                   "403": error_response("an upload-scoped token") }
                }
            },
            "/api/tokens/{id}/revoke": { "post": {
                "summary": "Revoke an API token (own; admins: anyone's); audited; revoking twice changes nothing",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": { "200": { "description": "ApiToken, now revoked", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/ApiToken" } } } },
                               "401": error_response("not logged in"),
                               "403": error_response("CSRF token missing, or an upload-scoped token"),
                               "404": error_response("no such token, or not yours") }
            } },
            "/api/atlases": {
                "post": {
                    "summary": "Publish an atlas (admins and instructors; audited)",
                    "description": "A tar archive of atlas.toml, validation.toml, the two volumes and the record's scripts/*.txt (stylet atlas publish makes it). The service loads it, checks the validation record against its content hash and runs the smoke test again before it keeps it by content hash and lists it in the catalogue.",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "requestBody": { "required": true, "content": { "application/x-tar": { "schema": { "type": "string", "format": "binary" } } } },
                    "responses": {
                        "201": { "description": "{content_hash, name, status: published, smoke, atlas}" },
                        "200": { "description": "{content_hash, name, status: already_published}" },
                        "400": error_response("empty body"),
                        "401": error_response("not logged in"),
                        "403": error_response("not an admin or instructor, CSRF token missing, or an upload-scoped token"),
                        "409": error_response("the catalogue is full"),
                        "411": error_response("no Content-Length"),
                        "413": error_response("over the atlas size limit"),
                        "415": error_response("not application/x-tar"),
                        "422": error_response("not a valid archive, a damaged atlas, not validated, or its smoke test failed"),
                        "503": error_response("two other publications are under way")
                    }
                },
                "get": {
                    "summary": "The scenario catalogue: every atlas this server scores sessions on",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "responses": { "200": { "description": "{atlases: [{content_hash, name, description, origin, published_by, published_at, scenarios, paths, structures, dims, spacing_mm, sessions}]}" }, "401": error_response("not logged in") }
                }
            },
            "/api/sessions": {
                "post": {
                    "summary": "Upload a session file",
                    "description": "API tokens of either scope may upload (the desktop simulator).",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "requestBody": { "required": true, "content": { "application/octet-stream": { "schema": { "type": "string", "format": "binary" } } } },
                    "responses": {
                        "201": { "description": "{id, status: queued} for new bytes" },
                        "200": { "description": "{id, status} of the same bytes uploaded before" },
                        "400": error_response("empty body"),
                        "401": error_response("not logged in"),
                        "403": error_response("may not upload for this trainee, or CSRF token missing"),
                        "413": error_response("over the size limit"),
                        "422": error_response("not a valid session file, unknown atlas, or unknown trainee")
                    }
                },
                "get": {
                    "summary": "Sessions the caller may see, newest first",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "responses": { "200": { "description": "{sessions: [Session]}" }, "401": error_response("not logged in") }
                }
            },
            "/api/sessions/{id}/override": { "post": {
                "summary": "Override the grade with a reason (the trainee's instructors, admins; audited)",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "requestBody": { "required": true, "content": { "application/json": { "schema": {
                    "type": "object", "required": ["score", "passed", "reason"],
                    "properties": { "score": { "type": "number", "minimum": 0, "maximum": 100 }, "passed": { "type": "boolean" }, "reason": { "type": "string" } } } } } },
                "responses": { "201": { "description": "stored" }, "400": error_response("bad body"), "403": error_response("not a reviewer of this trainee"), "404": error_response("no such session") }
            } },
            "/api/sessions/{id}/comments": { "post": {
                "summary": "Comment on a session (the trainee's instructors, admins)",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "requestBody": { "required": true, "content": { "application/json": { "schema": {
                    "type": "object", "required": ["body"], "properties": { "body": { "type": "string" }, "at_s": { "type": "number", "minimum": 0, "description": "moment of the session (s from its start) the comment points at" } } } } } },
                "responses": { "201": { "description": "stored" }, "400": error_response("bad body"), "403": error_response("not a reviewer of this trainee"), "404": error_response("no such session") }
            } },
            "/api/sessions/{id}/expert": {
                "post": {
                    "summary": "Mark the session as an expert reference of its scenario (the trainee's instructors, admins; audited). It must be scored, complete, its replay verified",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                    "responses": { "201": { "description": "{session, expert: true}" }, "403": error_response("not a reviewer of this trainee"), "404": error_response("no such session"), "409": error_response("not scored, incomplete, not verified, or the scenario has the most references") }
                },
                "delete": {
                    "summary": "Unmark an expert reference (the trainee's instructors, admins; audited)",
                    "security": [{ "cookie": [] }, { "token": [] }],
                    "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                    "responses": { "200": { "description": "{session, expert: false}" }, "403": error_response("not a reviewer of this trainee"), "404": error_response("no such session") }
                }
            },
            "/api/sessions/{id}/benchmark": { "get": {
                "summary": "The expert benchmark of the session's scenario (mean and spread per metric over its expert references) and the session's metrics against it",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": { "200": { "description": "{scenario, exercise, experts, metrics: [{metric, mean, spread}], expert, comparison: [{metric, value, mean, spread, spreads_from_mean}], references (staff only)}" }, "404": error_response("no such session") }
            } },
            "/api/trainees/{username}/progress": { "get": {
                "summary": "A trainee's scored sessions per difficulty, in upload order (overrides applied)",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "username", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": { "200": { "description": "{trainee, progress: {beginner: [...], advanced: [...], expert: [...]}}" }, "404": error_response("no such trainee, or not yours to see") }
            } },
            "/api/cohorts/{name}/summary": { "get": {
                "summary": "Per trainee of a cohort: sessions, scored, passed, mean score, last upload",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "name", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": { "200": { "description": "{cohort, trainees: [...]}" }, "403": error_response("not an instructor of this cohort"), "404": error_response("no such cohort") }
            } },
            "/api/export/sessions.csv": { "get": {
                "summary": "One CSV row per visible session (columns in docs/api.md)",
                "security": [{ "cookie": [] }, { "token": [] }],
                "responses": { "200": { "description": "text/csv" }, "403": error_response("trainees have no export") }
            } },
            "/api/sessions/{id}/file": { "get": {
                "summary": "The session file as uploaded (application/octet-stream, streamed)",
                "description": "For whoever may see the session; API tokens of either scope (the simulator's replay viewer fetches sessions with its upload token).",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": {
                    "200": { "description": "The session file (docs/session-format.md)" },
                    "401": error_response("not logged in"),
                    "404": error_response("no such session, or not yours to see")
                }
            } },
            "/api/sessions/{id}": { "get": {
                "summary": "One session and its score",
                "description": "API tokens of either scope may read it (the simulator polls the status of its upload); every other route refuses upload-scoped tokens with 403.",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": {
                    "200": { "description": "Session", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Session" } } } },
                    "401": error_response("not logged in"),
                    "404": error_response("no such session, or not yours to see")
                }
            }, "delete": {
                "summary": "Delete a session (admins): rows, file, trace and figures; audited",
                "security": [{ "cookie": [] }, { "token": [] }],
                "parameters": [{ "name": "id", "in": "path", "required": true, "schema": { "type": "string" } }],
                "responses": {
                    "200": { "description": "Deleted: {\"deleted\": id}" },
                    "401": error_response("not logged in"),
                    "403": error_response("not an admin, or no CSRF token"),
                    "404": error_response("no such session")
                }
            } }
        }
    })
}
