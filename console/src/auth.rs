//! Who may use the console: the users and roles of a cell's `[zenoh.access]` (operators start
//! scans, readers only look), signed in with the same passwords. Sessions are random tokens in
//! an HttpOnly, SameSite=Strict cookie; each carries its own CSRF token that every change must
//! send back. Without access control everyone is an operator, which the console allows on
//! loopback only.

use std::collections::HashMap;
use std::io::Read as _;
use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use anyhow::{bail, Context, Result};

/// The session cookie's name.
pub const COOKIE: &str = "ris_console";
/// How long a session lasts without use.
const IDLE: Duration = Duration::from_secs(8 * 3600);
/// Most sessions held at once (the oldest are dropped).
const MAX_SESSIONS: usize = 10_000;

/// What a user may do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// Look only.
    Reader,
    /// Look and start scans.
    Operator,
}

/// A signed-in (or, without access control, anonymous) browser session.
#[derive(Clone, Debug)]
pub struct Session {
    /// User name (`anonymous` without access control).
    pub user: String,
    /// Role.
    pub role: Role,
    /// The token every change must carry.
    pub csrf: String,
    seen: Instant,
}

/// The users, their roles and the sessions.
pub struct Auth {
    users: Option<HashMap<String, (String, Role)>>,
    sessions: Mutex<HashMap<String, Session>>,
}

/// 32 random bytes from the kernel, hex-encoded.
pub fn token() -> Result<String> {
    let mut bytes = [0u8; 32];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut bytes))
        .context("reading /dev/urandom for a session token")?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Equal without an early exit on the first differing byte.
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len()
        && a.bytes()
            .zip(b.bytes())
            .fold(0u8, |acc, (x, y)| acc | (x ^ y))
            == 0
}

impl Auth {
    /// No access control: everyone is an operator.
    pub fn open() -> Auth {
        Auth {
            users: None,
            sessions: Mutex::new(HashMap::new()),
        }
    }

    /// The users of `config`'s `[zenoh.access]` (a cell configuration, or any TOML file with
    /// that table): its `users` file of `user:password` lines (relative to `config`'s
    /// directory), its `operators` and `readers`; users in neither list may not sign in.
    pub fn from_cell_config(config: &Path) -> Result<Auth> {
        let text = std::fs::read_to_string(config)
            .with_context(|| format!("--access: reading {}", config.display()))?;
        let file: toml::Value = toml::from_str(&text)
            .map_err(|e| anyhow::anyhow!("--access {}: {e}", config.display()))?;
        let Some(table) = file.get("zenoh").and_then(|z| z.get("access")).cloned() else {
            bail!(
                "--access {}: the file has no [zenoh.access] table with users and roles",
                config.display()
            );
        };
        let mut access: ris_daemon::config::AccessSection = table
            .try_into()
            .map_err(|e| anyhow::anyhow!("--access {}: [zenoh.access]: {e}", config.display()))?;
        if access.users.is_relative() {
            access.users = config
                .parent()
                .unwrap_or(Path::new("."))
                .join(&access.users);
        }
        let text = std::fs::read_to_string(&access.users)
            .with_context(|| format!("[zenoh.access] users: reading {}", access.users.display()))?;
        let mut users = HashMap::new();
        for (n, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let Some((user, password)) = line.split_once(':') else {
                bail!(
                    "{} line {}: expected `user:password`",
                    access.users.display(),
                    n + 1
                );
            };
            let role = if access.operators.iter().any(|o| o == user) {
                Role::Operator
            } else if access.readers.iter().any(|r| r == user) {
                Role::Reader
            } else {
                continue;
            };
            users.insert(user.to_string(), (password.to_string(), role));
        }
        if users.is_empty() {
            bail!(
                "--access {}: no user of {} is an operator or a reader",
                config.display(),
                access.users.display()
            );
        }
        Ok(Auth {
            users: Some(users),
            sessions: Mutex::new(HashMap::new()),
        })
    }

    /// Whether users must sign in.
    pub fn required(&self) -> bool {
        self.users.is_some()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HashMap<String, Session>> {
        self.sessions.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn insert(&self, user: &str, role: Role) -> Result<(String, Session)> {
        let id = token()?;
        let session = Session {
            user: user.to_string(),
            role,
            csrf: token()?,
            seen: Instant::now(),
        };
        let mut s = self.lock();
        s.retain(|_, v| v.seen.elapsed() < IDLE);
        if s.len() >= MAX_SESSIONS {
            if let Some(oldest) = s.iter().min_by_key(|(_, v)| v.seen).map(|(k, _)| k.clone()) {
                s.remove(&oldest);
            }
        }
        s.insert(id.clone(), session.clone());
        Ok((id, session))
    }

    /// Sign `user` in: the new session's id, or `None` for a wrong user or password.
    pub fn sign_in(&self, user: &str, password: &str) -> Result<Option<(String, Session)>> {
        let Some(users) = &self.users else {
            return self.insert("anonymous", Role::Operator).map(Some);
        };
        match users.get(user) {
            Some((p, role)) if same(p, password) => self.insert(user, *role).map(Some),
            _ => Ok(None),
        }
    }

    /// The session of cookie value `id`, refreshed; without access control a missing one is
    /// made (anonymous operator) and its new id returned beside it.
    pub fn session(&self, id: Option<&str>) -> Result<Option<(Option<String>, Session)>> {
        if let Some(id) = id {
            let mut s = self.lock();
            if let Some(session) = s.get_mut(id) {
                if session.seen.elapsed() < IDLE {
                    session.seen = Instant::now();
                    return Ok(Some((None, session.clone())));
                }
                s.remove(id);
            }
        }
        if self.users.is_none() {
            let (id, session) = self.insert("anonymous", Role::Operator)?;
            return Ok(Some((Some(id), session)));
        }
        Ok(None)
    }

    /// End a session.
    pub fn sign_out(&self, id: &str) {
        self.lock().remove(id);
    }
}

/// The `Set-Cookie` value of session `id`.
pub fn cookie(id: &str) -> String {
    format!("{COOKIE}={id}; HttpOnly; SameSite=Strict; Path=/")
}

/// The session id a `Cookie` header carries.
pub fn cookie_value(header: &str) -> Option<&str> {
    header
        .split(';')
        .filter_map(|c| c.trim().split_once('='))
        .find(|(k, _)| *k == COOKIE)
        .map(|(_, v)| v)
}

/// Whether `token` is the session's CSRF token.
pub fn csrf_ok(session: &Session, token: &str) -> bool {
    same(&session.csrf, token)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn users_sign_in_with_their_role_and_nobody_else() {
        let dir = tempfile::tempdir().expect("tmp");
        std::fs::write(
            dir.path().join("users.txt"),
            "op:secret\nrd:look\nother:x\n",
        )
        .expect("users");
        let config = dir.path().join("cell.toml");
        std::fs::write(
            &config,
            "[zenoh.access]\nusers = \"users.txt\"\noperators = [\"op\"]\nreaders = [\"rd\"]\n",
        )
        .expect("config");
        let auth = Auth::from_cell_config(&config).expect("users and roles");
        let none = dir.path().join("none.toml");
        std::fs::write(&none, "[cell]\nname = \"c\"\n").expect("write");
        let e = Auth::from_cell_config(&none).err().expect("refused");
        assert!(format!("{e:#}").contains("[zenoh.access]"), "{e:#}");
        assert!(auth.required());
        let (id, s) = auth
            .sign_in("op", "secret")
            .expect("ok")
            .expect("signed in");
        assert_eq!(s.role, Role::Operator);
        assert!(auth.sign_in("op", "wrong").expect("ok").is_none());
        assert!(
            auth.sign_in("other", "x").expect("ok").is_none(),
            "no role, no entry"
        );
        let (_, r) = auth.sign_in("rd", "look").expect("ok").expect("reader");
        assert_eq!(r.role, Role::Reader);
        let (fresh, again) = auth.session(Some(&id)).expect("ok").expect("known");
        assert!(fresh.is_none() && again.user == "op" && csrf_ok(&again, &s.csrf));
        assert!(!csrf_ok(&again, "forged"));
        assert!(auth.session(Some("unknown")).expect("ok").is_none());
        auth.sign_out(&id);
        assert!(auth.session(Some(&id)).expect("ok").is_none());
    }

    #[test]
    fn without_access_control_every_browser_is_an_anonymous_operator() {
        let auth = Auth::open();
        let (id, s) = auth.session(None).expect("ok").expect("made");
        assert_eq!(s.role, Role::Operator);
        let id = id.expect("a new cookie");
        assert_eq!(
            cookie_value(&format!(
                "a=b; {}",
                cookie(&id).split(';').next().expect("kv")
            )),
            Some(id.as_str())
        );
    }
}
