//! The console's HTTP side (axum): pages, fragments the live page refreshes, the deviation
//! cloud for the 3D view, exports, server-sent events, sign-in and the start of a scan.

use std::convert::Infallible;
use std::sync::Arc;

use axum::extract::{Path, Query, State};
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::sse::{Event as SseEvent, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use axum::{Form, Router};
use ris_daemon::protocol::{ScanItem, ScanMode, ScanRequest, MAX_TAG};
use serde::Deserialize;
use serde_json::Value;
use tokio::sync::broadcast::error::RecvError;
use tokio_util::sync::CancellationToken;

use crate::auth::{self, Auth, Role, Session};
use crate::export;
use crate::fabric::Fabric;
use crate::history::Filter;
use crate::pages;

/// Most points the 3D view is sent (a larger cloud is decimated evenly).
pub const VIEW_POINTS: usize = 400_000;

/// What every handler shares.
pub struct App {
    /// The fabric and history.
    pub fabric: Arc<Fabric>,
    /// Users and sessions.
    pub auth: Auth,
    /// Ends the event streams when the console stops.
    pub shutdown: CancellationToken,
}

type Shared = State<Arc<App>>;

/// The router of every page.
pub fn router(app: Arc<App>) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/login", get(login_page).post(login))
        .route("/logout", post(logout))
        .route("/scans", get(scans))
        .route("/scan", post(start_scan))
        .route("/cells/{cell}/scans/{id}", get(result))
        .route("/cells/{cell}/stream/{picture}", get(stream_picture))
        .route("/cells/{cell}/scans/{id}/map.png", get(map))
        .route("/cells/{cell}/scans/{id}/deviation.bin", get(deviation))
        .route("/cells/{cell}/scans/{id}/page", get(cell_page))
        .route("/cells/{cell}/scans/{id}/report.json", get(report_json))
        .route("/parts/{part}", get(trend))
        .route("/parts/{part}/{file}", get(export))
        .route("/fragment/cells", get(fragment_cells))
        .route("/fragment/latest", get(fragment_latest))
        .route("/fragment/scan/{cell}/{id}", get(fragment_scan))
        .route("/events", get(events))
        .route("/assets/{name}", get(asset))
        .with_state(app)
}

/// A page or a refusal in words.
pub struct Failure(StatusCode, String);

impl IntoResponse for Failure {
    fn into_response(self) -> Response {
        (
            self.0,
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            self.1,
        )
            .into_response()
    }
}

impl From<anyhow::Error> for Failure {
    fn from(e: anyhow::Error) -> Failure {
        Failure(StatusCode::BAD_GATEWAY, format!("{e:#}"))
    }
}

impl From<crate::history::HistoryError> for Failure {
    fn from(e: crate::history::HistoryError) -> Failure {
        Failure(StatusCode::INTERNAL_SERVER_ERROR, e.to_string())
    }
}

/// The session of the request, or the response that sends the browser to sign in.
struct Visitor {
    session: Session,
    /// A cookie to set (a new anonymous session).
    set_cookie: Option<String>,
}

fn visitor(app: &App, headers: &HeaderMap) -> Result<Visitor, Box<Response>> {
    let id = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(auth::cookie_value);
    match app.auth.session(id) {
        Ok(Some((new, session))) => Ok(Visitor {
            session,
            set_cookie: new.map(|id| auth::cookie(&id)),
        }),
        Ok(None) => Err(Box::new(Redirect::to("/login").into_response())),
        Err(e) => Err(Box::new(
            Failure(StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}")).into_response(),
        )),
    }
}

fn respond(v: &Visitor, body: impl IntoResponse) -> Response {
    let mut r = body.into_response();
    if let Some(c) = v
        .set_cookie
        .as_ref()
        .and_then(|c| HeaderValue::from_str(c).ok())
    {
        r.headers_mut().insert(header::SET_COOKIE, c);
    }
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    r
}

macro_rules! visitor_or_return {
    ($app:expr, $headers:expr) => {
        match visitor(&$app, &$headers) {
            Ok(v) => v,
            Err(r) => return *r,
        }
    };
}

async fn index(State(app): Shared, headers: HeaderMap) -> Response {
    let v = visitor_or_return!(app, headers);
    match pages::index(&app.fabric, &v.session) {
        Ok(html) => respond(&v, Html(html)),
        Err(e) => Failure::from(e).into_response(),
    }
}

async fn fragment_cells(State(app): Shared, headers: HeaderMap) -> Response {
    let v = visitor_or_return!(app, headers);
    match pages::cells_table(&app.fabric) {
        Ok(html) => respond(&v, Html(html)),
        Err(e) => Failure::from(e).into_response(),
    }
}

async fn fragment_latest(State(app): Shared, headers: HeaderMap) -> Response {
    let v = visitor_or_return!(app, headers);
    match pages::latest(&app.fabric) {
        Ok(html) => respond(&v, Html(html)),
        Err(e) => Failure::from(e).into_response(),
    }
}

async fn fragment_scan(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, id)): Path<(String, String)>,
) -> Response {
    let v = visitor_or_return!(app, headers);
    respond(&v, Html(pages::progress(&app.fabric, &cell, &id)))
}

async fn login_page(State(app): Shared) -> Response {
    if !app.auth.required() {
        return Redirect::to("/").into_response();
    }
    Html(pages::login(None)).into_response()
}

#[derive(Deserialize)]
struct LoginForm {
    user: String,
    password: String,
}

async fn login(State(app): Shared, Form(f): Form<LoginForm>) -> Response {
    match app.auth.sign_in(&f.user, &f.password) {
        Ok(Some((id, _))) => {
            let mut r = Redirect::to("/").into_response();
            if let Ok(c) = HeaderValue::from_str(&auth::cookie(&id)) {
                r.headers_mut().insert(header::SET_COOKIE, c);
            }
            r
        }
        Ok(None) => (
            StatusCode::UNAUTHORIZED,
            Html(pages::login(Some("Wrong user or password."))),
        )
            .into_response(),
        Err(e) => Failure(StatusCode::INTERNAL_SERVER_ERROR, format!("{e:#}")).into_response(),
    }
}

#[derive(Deserialize)]
struct CsrfForm {
    csrf: String,
}

async fn logout(State(app): Shared, headers: HeaderMap, Form(f): Form<CsrfForm>) -> Response {
    let v = visitor_or_return!(app, headers);
    if !auth::csrf_ok(&v.session, &f.csrf) {
        return Failure(
            StatusCode::FORBIDDEN,
            "the form's token is stale: reload the page".into(),
        )
        .into_response();
    }
    if let Some(id) = headers
        .get(header::COOKIE)
        .and_then(|v| v.to_str().ok())
        .and_then(auth::cookie_value)
    {
        app.auth.sign_out(id);
    }
    let mut r = Redirect::to("/login").into_response();
    r.headers_mut().insert(
        header::SET_COOKIE,
        HeaderValue::from_static("ris_console=; HttpOnly; SameSite=Strict; Path=/; Max-Age=0"),
    );
    r
}

async fn scans(State(app): Shared, headers: HeaderMap, Query(filter): Query<Filter>) -> Response {
    let v = visitor_or_return!(app, headers);
    match app.fabric.history.search(&filter) {
        Ok(rows) => respond(&v, Html(pages::scans(&v.session, &filter, &rows))),
        Err(e) => Failure::from(e).into_response(),
    }
}

#[derive(Deserialize)]
struct StartForm {
    csrf: String,
    cell: String,
    #[serde(default)]
    mode: String,
    #[serde(default)]
    part: String,
    #[serde(default)]
    tag: String,
    #[serde(default)]
    serial: String,
}

async fn start_scan(State(app): Shared, headers: HeaderMap, Form(f): Form<StartForm>) -> Response {
    let cell = f.cell.clone();
    let v = visitor_or_return!(app, headers);
    if !auth::csrf_ok(&v.session, &f.csrf) {
        return Failure(
            StatusCode::FORBIDDEN,
            "the form's token is stale: reload the page".into(),
        )
        .into_response();
    }
    if v.session.role != Role::Operator {
        return Failure(
            StatusCode::FORBIDDEN,
            format!("{} is a reader: only operators start scans", v.session.user),
        )
        .into_response();
    }
    let text = |s: &str| Some(s.trim().to_string()).filter(|s| !s.is_empty());
    let mode = if f.mode.is_empty() {
        None
    } else {
        match ScanMode::parse(&f.mode) {
            Some(ScanMode::Verify) | None => {
                return Failure(
                    StatusCode::BAD_REQUEST,
                    format!("mode {:?}: gray, adaptive or single-shot", f.mode),
                )
                .into_response()
            }
            m => m,
        }
    };
    for (name, value) in [("tag", &f.tag), ("serial", &f.serial)] {
        if value.chars().count() > MAX_TAG {
            return Failure(
                StatusCode::BAD_REQUEST,
                format!("{name}: at most {MAX_TAG} characters"),
            )
            .into_response();
        }
    }
    let request = ScanRequest {
        mode,
        part: text(&f.part),
        tag: text(&f.tag),
        serial: text(&f.serial),
        operator: Some(v.session.user.clone()),
        ..ScanRequest::default()
    };
    match app.fabric.start_scan(&cell, &request).await {
        Ok(reply) => respond(
            &v,
            Redirect::to(&format!(
                "/cells/{}/scans/{}",
                pages::url(&cell),
                pages::url(&reply.scan_id)
            )),
        ),
        Err(e) => Failure(StatusCode::CONFLICT, format!("{e:#}")).into_response(),
    }
}

async fn result(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, id)): Path<(String, String)>,
) -> Response {
    let v = visitor_or_return!(app, headers);
    let record = match app.fabric.history.scan(&cell, &id) {
        Ok(r) => r,
        Err(e) => return Failure::from(e).into_response(),
    };
    let Some(record) = record else {
        // Not finished (or not yet recorded): the live progress of it.
        return respond(
            &v,
            Html(pages::pending(&app.fabric, &v.session, &cell, &id)),
        );
    };
    let report: Option<Value> = if record.part.is_some() {
        app.fabric
            .fetch(&ScanItem::Report.key(&cell, &id))
            .await
            .ok()
            .and_then(|b| serde_json::from_slice(&b).ok())
    } else {
        None
    };
    let values = match app.fabric.history.values(&cell, &id) {
        Ok(v) => v,
        Err(e) => return Failure::from(e).into_response(),
    };
    respond(
        &v,
        Html(pages::result(&v.session, &record, report.as_ref(), &values)),
    )
}

async fn stored(
    app: &App,
    headers: &HeaderMap,
    key: String,
    content_type: &'static str,
) -> Response {
    let v = visitor_or_return!(app, headers);
    match app.fabric.fetch(&key).await {
        Ok(bytes) => respond(&v, ([(header::CONTENT_TYPE, content_type)], bytes)),
        Err(e) => Failure(StatusCode::NOT_FOUND, format!("{e:#}")).into_response(),
    }
}

/// `/cells/<cell>/stream/<sensor>.png`: the sensor's latest fusion picture.
async fn stream_picture(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, picture)): Path<(String, String)>,
) -> Response {
    let v = visitor_or_return!(app, headers);
    let Some(sensor) = picture.strip_suffix(".png") else {
        return StatusCode::NOT_FOUND.into_response();
    };
    match app.fabric.picture(&cell, sensor) {
        Some(png) => respond(&v, ([(header::CONTENT_TYPE, "image/png")], png.to_vec())),
        None => Failure(
            StatusCode::NOT_FOUND,
            format!("{sensor} of {cell} has streamed no picture since the console started"),
        )
        .into_response(),
    }
}

async fn map(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, id)): Path<(String, String)>,
) -> Response {
    stored(&app, &headers, ScanItem::Map.key(&cell, &id), "image/png").await
}

async fn cell_page(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, id)): Path<(String, String)>,
) -> Response {
    let mut r = stored(
        &app,
        &headers,
        ScanItem::Page.key(&cell, &id),
        "text/html; charset=utf-8",
    )
    .await;
    // risd's page is self-contained: nothing it carries may run scripts or load anything.
    r.headers_mut().insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static("default-src 'none'; img-src data:; style-src 'unsafe-inline'"),
    );
    r
}

async fn report_json(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, id)): Path<(String, String)>,
) -> Response {
    stored(
        &app,
        &headers,
        ScanItem::Report.key(&cell, &id),
        "application/json",
    )
    .await
}

/// The deviation cloud for the 3D view: `u32` points sent, `u32` points in the scan, then
/// per point `f32` x, y, z (mm, CAD frame) and deviation (mm), little-endian; at most
/// [`VIEW_POINTS`], taken evenly.
async fn deviation(
    State(app): Shared,
    headers: HeaderMap,
    Path((cell, id)): Path<(String, String)>,
) -> Response {
    let v = visitor_or_return!(app, headers);
    let bytes = match app.fabric.fetch(&ScanItem::Deviation.key(&cell, &id)).await {
        Ok(b) => b,
        Err(e) => return Failure(StatusCode::NOT_FOUND, format!("{e:#}")).into_response(),
    };
    let body = tokio::task::spawn_blocking(move || view_cloud(&bytes, VIEW_POINTS)).await;
    match body {
        Ok(Ok(body)) => respond(
            &v,
            ([(header::CONTENT_TYPE, "application/octet-stream")], body),
        ),
        Ok(Err(e)) => Failure(StatusCode::BAD_GATEWAY, e).into_response(),
        Err(e) => Failure(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

/// The 3D view's binary of a deviation PLY: `u32` points sent, `u32` points in the cloud, then
/// per point `f32` x, y, z and deviation, little-endian; at most `max` points, taken evenly.
pub fn view_cloud(ply: &[u8], max: usize) -> Result<Vec<u8>, String> {
    let cloud = ris_core::cloud::PointCloud::from_ply(ply, std::path::Path::new("deviation.ply"))
        .map_err(|e| e.to_string())?;
    let dev = cloud
        .scalars
        .iter()
        .find(|s| s.name == "deviation")
        .ok_or("the deviation cloud has no `deviation` property")?;
    let n = cloud.points.len();
    let step = n.div_ceil(max.max(1)).max(1);
    let sent = n.div_ceil(step);
    let mut out = Vec::with_capacity(8 + sent * 16);
    out.extend_from_slice(&(sent as u32).to_le_bytes());
    out.extend_from_slice(&(n as u32).to_le_bytes());
    for i in (0..n).step_by(step) {
        let p = cloud.points[i];
        for x in [p[0], p[1], p[2], dev.values[i]] {
            out.extend_from_slice(&x.to_le_bytes());
        }
    }
    Ok(out)
}

#[derive(Deserialize)]
struct TrendQuery {
    #[serde(default)]
    c: Option<String>,
}

async fn trend(
    State(app): Shared,
    headers: HeaderMap,
    Path(part): Path<String>,
    Query(q): Query<TrendQuery>,
) -> Response {
    let v = visitor_or_return!(app, headers);
    match pages::trend(&app.fabric, &v.session, &part, q.c.as_deref()) {
        Ok(html) => respond(&v, Html(html)),
        Err(e) => Failure::from(e).into_response(),
    }
}

/// Every scan of `part` (oldest first) with a value per characteristic.
fn part_table(
    fabric: &Fabric,
    part: &str,
) -> anyhow::Result<(Vec<crate::characteristic::Characteristic>, Vec<export::Row>)> {
    let h = &fabric.history;
    let mut scans = h.search(&Filter {
        part: Some(part.to_string()),
        limit: Some(10_000),
        ..Filter::default()
    })?;
    scans.reverse();
    let names = h.characteristics(part)?;
    let mut columns: Vec<Option<crate::characteristic::Characteristic>> = vec![None; names.len()];
    let mut rows = Vec::with_capacity(scans.len());
    for s in scans {
        let values = h.values(&s.cell, &s.scan_id)?;
        let mut row = vec![None; names.len()];
        for c in values {
            if let Some(i) = names.iter().position(|n| *n == c.name) {
                row[i] = Some(c.value);
                columns[i].get_or_insert(c);
            }
        }
        rows.push((s, row));
    }
    Ok((columns.into_iter().flatten().collect(), rows))
}

/// `/parts/<part>/export.csv` or `export.dfq` (AQDEF): every scan of the part.
async fn export(
    State(app): Shared,
    headers: HeaderMap,
    Path((part, file)): Path<(String, String)>,
) -> Response {
    let v = visitor_or_return!(app, headers);
    let (kind, render): (&str, export::Render) = match file.as_str() {
        "export.csv" => ("text/csv; charset=utf-8", export::csv),
        "export.dfq" => ("text/plain; charset=utf-8", export::aqdef),
        _ => return StatusCode::NOT_FOUND.into_response(),
    };
    // One query per scan: off the async runtime.
    let (fabric, p) = (app.fabric.clone(), part.clone());
    let table = tokio::task::spawn_blocking(move || part_table(&fabric, &p)).await;
    match table
        .map_err(|e| anyhow::anyhow!("exporting {part}: {e}"))
        .and_then(|t| t)
    {
        Ok((columns, rows)) => respond(
            &v,
            (
                [
                    (header::CONTENT_TYPE, kind.to_string()),
                    (
                        header::CONTENT_DISPOSITION,
                        format!(
                            "attachment; filename=\"{}.{}\"",
                            pages::file_name(&part),
                            &file[7..]
                        ),
                    ),
                ],
                render(&part, &columns, &rows),
            ),
        ),
        Err(e) => Failure::from(e).into_response(),
    }
}

async fn events(State(app): Shared, headers: HeaderMap) -> Response {
    let v = visitor_or_return!(app, headers);
    let state = (app.fabric.subscribe(), app.shutdown.clone());
    let stream = futures_util::stream::unfold(state, |(mut rx, stop)| async move {
        loop {
            let event = tokio::select! {
                _ = stop.cancelled() => return None,
                r = rx.recv() => r,
            };
            match event {
                Ok(e) => {
                    if let Ok(json) = serde_json::to_string(&e) {
                        return Some((
                            Ok::<_, Infallible>(SseEvent::default().data(json)),
                            (rx, stop),
                        ));
                    }
                }
                // A slow browser missed events: it refreshes on the next one.
                Err(RecvError::Lagged(_)) => continue,
                Err(RecvError::Closed) => return None,
            }
        }
    });
    respond(&v, Sse::new(stream).keep_alive(KeepAlive::default()))
}

async fn asset(Path(name): Path<String>) -> Response {
    let (body, kind) = match name.as_str() {
        "console.css" => (pages::CSS, "text/css; charset=utf-8"),
        "console.js" => (pages::JS, "text/javascript; charset=utf-8"),
        "viewer.js" => (pages::VIEWER, "text/javascript; charset=utf-8"),
        _ => return StatusCode::NOT_FOUND.into_response(),
    };
    ([(header::CONTENT_TYPE, kind)], body).into_response()
}
