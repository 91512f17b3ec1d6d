"""A test LTI 1.3 platform (the LMS side) for Stylet's LTI integration tests.

The LTI work is done by lti1p3platform (PyPI, MIT), which scripts/lti-platform installs: its
Registration holds the platform's keys and Stylet's registration, FastAPIOIDCLogin builds the
third-party login initiation, FastapiMessageLaunch with LTIAdvantageMessageLaunchAbstract checks
the authentication request and builds and signs the id_token (deep linking and AGS claims
included) into its auto-submitting form, and LTI1P3PlatformConfAbstract checks the tool's signed
JWTs against the tool's key set (validate_deeplinking_resp, get_access_token) and the bearer
tokens it issued (validate_token). This file is only the glue: a FastAPI app, state in memory,
and the checks the library leaves to its caller (audiences, deployment id, echoed `data`, score
bodies).

    python tests/lti-platform/lms.py --port P --tool-url http://127.0.0.1:T \
        --client-id CID --deployment-id DID

Serves http://127.0.0.1:P, which is also the issuer. Stylet is registered with its OIDC login
initiation URL {tool}/lti/login, its launch and deep-linking launch URL {tool}/lti/launch and its
key set {tool}/lti/jwks (fetched afresh for every JWT of the tool's, so the tool may start after
the platform or change keys). Two RSA-2048 keys are made at start: the platform's, published at
/jwks (its kid is its RFC 7638 thumbprint, as the library names it), and a rogue one (kid
"rogue-1") that is never published. A deep-linked item's `url`, if any, is the target_link_uri of
its launches; the redirect_uri must still be the registered launch URL.

LTI endpoints: GET /jwks, GET /authorize, POST /deep-link-return, POST /token,
GET /lineitems, GET /lineitems/{n}, POST /lineitems/{n}/scores.
Test-only endpoints (what a user or an admin would do in an LMS, and what it recorded):
  GET /test/launch        a user opens an activity: kind=resource|deeplink, user, name, email,
                          role (Learner, Instructor or a role URI; comma-separated for several),
                          context, context_title, resource_link, tamper=none|wrong_aud|expired|
                          unknown_key; answers 302 to the tool's login initiation URL
  GET /test/content-items the resource links deep linking created, as JSON
  GET /test/scores/{n}    the score bodies line item n received, in order, as JSON
"""
import argparse  # noqa: E402
import html  # noqa: E402
import itertools  # noqa: E402
import json  # noqa: E402
import secrets  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from datetime import datetime  # noqa: E402

# lti1p3platform's template module imports pkg_resources, which warns that it is deprecated.
warnings.filterwarnings("ignore", message="pkg_resources is deprecated")

import jwt  # noqa: E402
import uvicorn  # noqa: E402
from fastapi import FastAPI, Form, Request  # noqa: E402
from fastapi.responses import HTMLResponse, JSONResponse, PlainTextResponse  # noqa: E402
from jwcrypto.jwk import JWK  # noqa: E402
from lti1p3platform.exceptions import PreflightRequestValidationException  # noqa: E402
from lti1p3platform.framework.fastapi.message_launch import FastapiMessageLaunch  # noqa: E402
from lti1p3platform.framework.fastapi.oidc_login import FastAPIOIDCLogin  # noqa: E402
from lti1p3platform.ltiplatform import LTI1P3PlatformConfAbstract  # noqa: E402
from lti1p3platform.message_launch import LTIAdvantageMessageLaunchAbstract  # noqa: E402
from lti1p3platform.registration import Registration  # noqa: E402
from lti1p3platform.score import ActivityProgress, GradeProgress  # noqa: E402

ROLE = "http://purl.imsglobal.org/vocab/lis/v2/membership#"
COURSE_OFFERING = "http://purl.imsglobal.org/vocab/lis/v2/course#CourseOffering"
CLAIM = "https://purl.imsglobal.org/spec/lti/claim/"
DL_DATA = "https://purl.imsglobal.org/spec/lti-dl/claim/data"
AGS = "https://purl.imsglobal.org/spec/lti-ags/scope/"
SCORE_TYPE = "application/vnd.ims.lis.v1.score+json"
ASSERTION_TYPE = "urn:ietf:params:oauth:client-assertion-type:jwt-bearer"

ARGS = None  # the command line: port, tool_url, client_id, deployment_id
ISS = ""
KEYS = {}  # "platform"/"rogue" -> (private PEM, public PEM)
PENDING = {}  # lti_message_hint -> the launch /test/launch asked for
ISSUED_DATA = set()  # the deep_linking_settings `data` values sent
ITEMS = {}  # "rl-N" -> content item made by deep linking (resource link rl-N, line item N)
LINE_ITEMS = {}  # "N" -> AGS line item
SCORES = {}  # "N" -> score bodies received
NUMBERS = itertools.count(1)

app = FastAPI()


def new_key():
    key = JWK.generate(kty="RSA", size=2048)
    return key.export_to_pem(private_key=True, password=None).decode(), key.export_to_pem().decode()


class Platform(LTI1P3PlatformConfAbstract):
    """Made anew for every request: the library keeps the last JWT it read on this object and
    caches the tool's key set on the Registration, which would pin the first key set it saw."""

    def init_platform_config(self, **kwargs):
        self.get_registration()

    def get_registration_by_params(self, **kwargs):
        tool = ARGS.tool_url
        private, public = KEYS["platform"]
        return (Registration().set_iss(ISS).set_client_id(ARGS.client_id)
                .set_deployment_id(ARGS.deployment_id).set_oidc_login_url(f"{tool}/lti/login")
                .set_launch_url(f"{tool}/lti/launch").set_deeplink_launch_url(f"{tool}/lti/launch")
                .set_tool_key_set_url(f"{tool}/lti/jwks")
                .set_platform_private_key(private).set_platform_public_key(public))


class OIDCLogin(FastAPIOIDCLogin):
    def set_lti_message_hint(self, **kwargs):
        self._lti_message_hint = kwargs["hint"]


class Launch(FastapiMessageLaunch, LTIAdvantageMessageLaunchAbstract):
    """The id_token for one pending launch; tampered after the library signed it, if asked."""

    def __init__(self, request, pending):
        super().__init__(request, Platform())
        self.pending = pending

    def prepare_launch(self, preflight_response):
        p = self.pending
        self.set_user_data(p["user"], p["roles"], p["name"], p["email"])
        self.set_launch_context_claim(p["context"], [COURSE_OFFERING], p["context_title"])
        if p["kind"] == "deeplink":
            self.set_dl(f"{ISS}/deep-link-return", title="Add a Stylet activity",
                        accept_types={"ltiResourceLink"}, extra_data=p["data"])
            return
        item = ITEMS.get(p["resource_link"])
        self.set_resource_link_claim(p["resource_link"], title=item and item["title"])
        if item:
            if item["url"]:
                self.set_launch_url(item["url"])
            if item["custom"]:
                self.set_custom_parameters_claim(item["custom"])
            self.set_ags(f"{ISS}/lineitems", item["lineitem_url"],
                         allow_creating_lineitems=False, results_service_enabled=False)

    def generate_launch_request(self):
        data = super().generate_launch_request()
        mode = self.pending["tamper"]
        if mode == "none":
            return data
        claims = jwt.decode(data["id_token"], options={"verify_signature": False})
        key, kid = KEYS["platform"][0], self._registration.get_kid()
        if mode == "wrong_aud":
            claims["aud"] = "someone-else"
        elif mode == "expired":
            now = int(time.time())
            claims["iat"], claims["exp"] = now - 7200, now - 3600
        elif mode == "unknown_key":
            key, kid = KEYS["rogue"][0], "rogue-1"
        data["id_token"] = Registration.encode_and_sign(claims, key, headers={"kid": kid})
        return data


def bad(message, status=400):
    return PlainTextResponse(message + "\n", status_code=status)


@app.get("/jwks")
def jwks():
    return Platform().get_jwks()


@app.get("/test/launch")
def test_launch(request: Request):
    q = request.query_params
    kind, tamper, user = q.get("kind", "resource"), q.get("tamper", "none"), q.get("user")
    if kind not in ("resource", "deeplink"):
        return bad("kind must be resource or deeplink")
    if tamper not in ("none", "wrong_aud", "expired", "unknown_key"):
        return bad("tamper must be none, wrong_aud, expired or unknown_key")
    if not user:
        return bad("user is required")
    if kind == "resource" and not q.get("resource_link"):
        return bad("resource_link is required for kind=resource")
    roles = [r if "://" in r else ROLE + r for r in q.get("role", "Learner").split(",") if r]
    hint = secrets.token_urlsafe(16)
    PENDING[hint] = {
        "kind": kind, "tamper": tamper, "user": user, "roles": roles, "name": q.get("name"),
        "email": q.get("email"), "context": q.get("context", "course-1"),
        "context_title": q.get("context_title", "Course 1"),
        "resource_link": q.get("resource_link"), "data": "dl-" + secrets.token_urlsafe(12),
    }
    if kind == "deeplink":
        ISSUED_DATA.add(PENDING[hint]["data"])
    login = OIDCLogin(request, Platform())
    login.set_lti_message_hint(hint=hint)
    if kind == "deeplink":
        login.set_deeplinking_launch_url()
    else:
        item = ITEMS.get(PENDING[hint]["resource_link"])
        if item and item["url"]:
            login.set_launch_url(item["url"])
    redirect = login.initiate_login(user)
    redirect.status_code = 302  # the library's RedirectResponse answers 307
    return redirect


@app.get("/authorize")
def authorize(request: Request):
    q = request.query_params
    pending = PENDING.get(q.get("lti_message_hint", ""))
    if pending is None:
        return bad("unknown lti_message_hint")
    if q.get("redirect_uri") != f"{ARGS.tool_url}/lti/launch":
        return bad(f"redirect_uri is not the registered launch URL {ARGS.tool_url}/lti/launch")
    if q.get("login_hint") != pending["user"]:
        return bad("login_hint is not the user of this launch")
    for name, want in (("scope", "openid"), ("response_type", "id_token"),
                       ("response_mode", "form_post"), ("prompt", "none")):
        if q.get(name, want if name == "prompt" else None) != want:
            return bad(f"{name} must be {want}")
    try:
        form = Launch(request, pending).lti_launch()
    except PreflightRequestValidationException:
        return bad("nonce, state, redirect_uri and the registered client_id are required")
    form.headers["content-type"] = "text/html; charset=utf-8"  # the library sets none
    return form


@app.post("/deep-link-return")
def deep_link_return(JWT: str = Form(None)):  # noqa: N803 (the form field's name)
    if not JWT:
        return bad("the JWT form field is missing")
    platform = Platform().set_accepted_deeplinking_types(["ltiResourceLink"])
    try:
        items = platform.validate_deeplinking_resp({"JWT": JWT})
    except Exception as e:  # the tool's key set, the signature, the message type, the item types
        return bad(f"deep linking response rejected: {type(e).__name__}: {e}")
    claims = jwt.decode(JWT, options={"verify_signature": False})
    aud = claims.get("aud")
    if ISS not in (aud if isinstance(aud, list) else [aud]):
        return bad(f"aud must be the platform issuer {ISS}")
    if claims.get("iss") != ARGS.client_id:
        return bad("iss must be the client id")
    if claims.get(CLAIM + "deployment_id") != ARGS.deployment_id:
        return bad("deployment_id is not this deployment")
    if claims.get(DL_DATA) not in ISSUED_DATA:
        return bad("data is not what the deep linking request sent")
    titles = []
    for item in items:
        n = str(next(NUMBERS))
        title, li = item.get("title") or f"Activity {n}", item.get("lineItem") or {}
        ITEMS[f"rl-{n}"] = {"resource_link_id": f"rl-{n}", "lineitem_url": f"{ISS}/lineitems/{n}",
                            "title": title, "url": item.get("url"),
                            "custom": item.get("custom") or {}, "line_item": item.get("lineItem")}
        LINE_ITEMS[n] = {"id": f"{ISS}/lineitems/{n}", "label": li.get("label") or title,
                         "scoreMaximum": li.get("scoreMaximum", 100), "resourceLinkId": f"rl-{n}",
                         **{k: li[k] for k in ("resourceId", "tag") if k in li}}
        SCORES[n] = []
        titles.append(html.escape(title))
    body = "".join(f"<p>Activity added: {t}</p>" for t in titles) or "<p>No activity added</p>"
    return HTMLResponse(f"<!DOCTYPE html><html><body>{body}</body></html>")


@app.get("/test/content-items")
def content_items():
    return list(ITEMS.values())


@app.post("/token")
def token(grant_type: str = Form(None), client_assertion_type: str = Form(None),
          client_assertion: str = Form(None), scope: str = Form(None)):
    def error(code, description):
        return JSONResponse({"error": code, "error_description": description}, status_code=400)

    form = {"grant_type": grant_type, "client_assertion_type": client_assertion_type,
            "client_assertion": client_assertion, "scope": scope}
    if None in form.values():
        return error("invalid_request", "grant_type, client_assertion_type, client_assertion "
                     "and scope are required")
    if grant_type != "client_credentials":
        return error("unsupported_grant_type", "grant_type must be client_credentials")
    if client_assertion_type != ASSERTION_TYPE:
        return error("invalid_request", f"client_assertion_type must be {ASSERTION_TYPE}")
    try:
        answer = Platform().get_access_token(form)
    except Exception as e:  # the tool's key set, the signature, exp
        return error("invalid_client", f"{type(e).__name__}: {e}")
    claims = jwt.decode(client_assertion, options={"verify_signature": False})
    aud = claims.get("aud")
    if not {f"{ISS}/token", ISS} & set(aud if isinstance(aud, list) else [aud]):
        return error("invalid_client", f"aud must be {ISS}/token (or the issuer)")
    if claims.get("iss") != ARGS.client_id or claims.get("sub") != ARGS.client_id:
        return error("invalid_client", "iss and sub must be the client id")
    return answer


def bearer(request, scopes):
    """None when the request's bearer token is valid and has one of `scopes`, else the answer."""
    auth = request.headers.get("authorization", "").split()
    if len(auth) != 2 or auth[0].lower() != "bearer":
        return bad("a bearer token is required", 401)
    try:
        allowed = Platform().validate_token(auth[1], allowed_scopes=scopes)
    except Exception as e:
        return bad(f"invalid token: {type(e).__name__}: {e}", 401)
    return None if allowed else bad(f"the token has none of the scopes {scopes}", 403)


@app.get("/lineitems")
def get_line_items(request: Request, resource_link_id: str = None):
    denied = bearer(request, [AGS + "lineitem.readonly", AGS + "lineitem"])
    if denied:
        return denied
    items = [li for li in LINE_ITEMS.values()
             if resource_link_id in (None, li["resourceLinkId"])]
    return JSONResponse(items, media_type="application/vnd.ims.lis.v2.lineitemcontainer+json")


@app.get("/lineitems/{n}")
def get_line_item(request: Request, n: str):
    denied = bearer(request, [AGS + "lineitem.readonly", AGS + "lineitem"])
    if denied:
        return denied
    if n not in LINE_ITEMS:
        return bad("no such line item", 404)
    return JSONResponse(LINE_ITEMS[n], media_type="application/vnd.ims.lis.v2.lineitem+json")


def score_problem(score):
    """What is wrong with an AGS score body, or None."""
    if not isinstance(score, dict):
        return "the body must be a JSON object"
    if not isinstance(score.get("userId"), str) or not score["userId"]:
        return "userId must be a non-empty string"
    given, maximum = score.get("scoreGiven"), score.get("scoreMaximum")
    for name, value in (("scoreGiven", given), ("scoreMaximum", maximum)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return f"{name} must be a number"
    if not 0 <= given <= maximum or maximum <= 0:
        return "0 <= scoreGiven <= scoreMaximum and scoreMaximum > 0 are required"
    for name, enum in (("activityProgress", ActivityProgress), ("gradingProgress", GradeProgress)):
        if score.get(name) not in [e.value for e in enum]:
            return f"{name} must be one of {[e.value for e in enum]}"
    try:
        stamp = datetime.fromisoformat(score["timestamp"].replace("Z", "+00:00"))
    except (KeyError, AttributeError, ValueError):
        return "timestamp must be an ISO 8601 date and time"
    return None if stamp.tzinfo else "timestamp must have a time zone"


@app.post("/lineitems/{n}/scores")
async def post_score(request: Request, n: str):
    denied = bearer(request, [AGS + "score"])
    if denied:
        return denied
    if request.headers.get("content-type", "").split(";")[0].strip().lower() != SCORE_TYPE:
        return bad(f"the content type must be {SCORE_TYPE}", 415)
    if n not in LINE_ITEMS:
        return bad("no such line item", 404)
    try:
        score = json.loads(await request.body())
    except ValueError:
        return bad("the body is not JSON")
    problem = score_problem(score)
    if problem:
        return bad(problem)
    SCORES[n].append(score)
    return {}


@app.get("/test/scores/{n}")
def test_scores(n: str):
    return SCORES[n] if n in SCORES else bad("no such line item", 404)


def main():
    global ARGS, ISS
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--tool-url", required=True, help="e.g. http://127.0.0.1:8080")
    parser.add_argument("--client-id", required=True)
    parser.add_argument("--deployment-id", required=True)
    ARGS = parser.parse_args()
    ARGS.tool_url = ARGS.tool_url.rstrip("/")
    ISS = f"http://127.0.0.1:{ARGS.port}"
    KEYS["platform"], KEYS["rogue"] = new_key(), new_key()
    uvicorn.run(app, host="127.0.0.1", port=ARGS.port, log_level="warning")


if __name__ == "__main__":
    main()
