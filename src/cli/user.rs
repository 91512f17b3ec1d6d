//! `stylet user list|add|disable|enable|passwd|set|import`: the service's accounts from the
//! command line, on the service's database (the same store calls as the admin page and
//! `/api/users`; audited with no actor). Passwords come on standard input, never as arguments.

use std::io::Read;
use std::path::PathBuf;

use anyhow::Context;
use clap::{Args, Subcommand};
use stylet_service::store::{AccountChange, Role, Store};

use super::serve;

#[derive(Debug, Subcommand)]
pub enum UserCommand {
    /// Add an account; the password is read from standard input.
    Add(serve::UserAddArgs),
    /// List accounts (username, role, cohorts, status).
    List(ListArgs),
    /// Disable an account: its logins and API tokens are refused at once; its sessions stay.
    Disable(NameArgs),
    /// Enable a disabled account again.
    Enable(NameArgs),
    /// Set a new password (read from standard input); the account's logins end.
    Passwd(PasswdArgs),
    /// Change an account's role and/or cohorts.
    Set(SetArgs),
    /// Import accounts from a CSV file (`username,role,cohort,password` per line): all or none.
    Import(ImportArgs),
}

#[derive(Debug, Args)]
pub struct Db {
    #[arg(long)]
    pub data_dir: PathBuf,
    /// Database URL (default: SQLite `stylet.db` in the data directory).
    #[arg(long)]
    pub database: Option<String>,
}

#[derive(Debug, Args)]
pub struct ListArgs {
    #[command(flatten)]
    db: Db,
    /// Only usernames containing this.
    #[arg(long)]
    search: Option<String>,
    /// Most accounts to print.
    #[arg(long, default_value_t = 1000)]
    limit: i64,
}

#[derive(Debug, Args)]
pub struct NameArgs {
    #[command(flatten)]
    db: Db,
    username: String,
}

#[derive(Debug, Args)]
pub struct PasswdArgs {
    #[command(flatten)]
    db: Db,
    username: String,
    /// Read the password from standard input (required: passwords never go on the command line).
    #[arg(long, required = true)]
    password_stdin: bool,
}

#[derive(Debug, Args)]
pub struct SetArgs {
    #[command(flatten)]
    db: Db,
    username: String,
    /// trainee, instructor, curriculum or admin.
    #[arg(long)]
    role: Option<String>,
    /// Its cohorts from now on, comma-separated (created if new; "" for none).
    #[arg(long)]
    cohorts: Option<String>,
}

#[derive(Debug, Args)]
pub struct ImportArgs {
    #[command(flatten)]
    db: Db,
    /// The CSV file (`-` for standard input).
    file: PathBuf,
}

pub(super) async fn open(db: &Db) -> anyhow::Result<Store> {
    std::fs::create_dir_all(&db.data_dir).with_context(|| format!("cannot create {}", db.data_dir.display()))?;
    let url = db
        .database
        .clone()
        .unwrap_or_else(|| format!("sqlite://{}?mode=rwc", db.data_dir.join("stylet.db").display()));
    Ok(Store::open(&url).await?)
}

pub(super) fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

fn read_stdin() -> anyhow::Result<String> {
    let mut text = String::new();
    std::io::stdin()
        .read_to_string(&mut text)
        .context("reading standard input")?;
    Ok(text)
}

async fn change(db: &Db, username: &str, change: AccountChange) -> anyhow::Result<()> {
    let store = open(db).await?;
    let row = store.update_user(username, &change, None).await?;
    sayf!(
        "{}: {}, cohorts [{}], {}",
        row.username,
        row.role,
        row.cohorts.join(", "),
        if row.disabled_at.is_some() {
            "disabled"
        } else {
            "active"
        }
    );
    Ok(())
}

pub fn run(cmd: UserCommand) -> anyhow::Result<()> {
    let rt = runtime()?;
    match cmd {
        UserCommand::Add(a) => serve::user(serve::UserCommand::Add(a)),
        UserCommand::List(a) => rt.block_on(async {
            let store = open(&a.db).await?;
            let search = a.search.as_deref().filter(|s| !s.is_empty());
            let (rows, total) = store.users_page(search, 0, a.limit.max(0)).await?;
            sayf!("{:<24} {:<11} {:<9} cohorts", "username", "role", "status");
            for u in &rows {
                let status = if u.disabled_at.is_some() { "disabled" } else { "active" };
                sayf!(
                    "{:<24} {:<11} {:<9} {}",
                    u.username,
                    u.role,
                    status,
                    u.cohorts.join(", ")
                );
            }
            if total > rows.len() as i64 {
                sayf!("… {} of {total} shown (--limit, --search)", rows.len());
            }
            Ok(())
        }),
        UserCommand::Disable(a) => rt.block_on(change(
            &a.db,
            &a.username,
            AccountChange {
                disabled: Some(true),
                ..Default::default()
            },
        )),
        UserCommand::Enable(a) => rt.block_on(change(
            &a.db,
            &a.username,
            AccountChange {
                disabled: Some(false),
                ..Default::default()
            },
        )),
        UserCommand::Passwd(a) => {
            let password = read_stdin()?.trim_end_matches(['\n', '\r']).to_string();
            rt.block_on(change(
                &a.db,
                &a.username,
                AccountChange {
                    password: Some(password),
                    ..Default::default()
                },
            ))
        }
        UserCommand::Set(a) => {
            let role = a.role.as_deref().map(Role::parse).transpose()?;
            let cohorts = a.cohorts.map(|c| {
                c.split(',')
                    .map(str::trim)
                    .filter(|c| !c.is_empty())
                    .map(str::to_string)
                    .collect()
            });
            if role.is_none() && cohorts.is_none() {
                anyhow::bail!("nothing to change: give --role and/or --cohorts");
            }
            rt.block_on(change(
                &a.db,
                &a.username,
                AccountChange {
                    role,
                    cohorts,
                    ..Default::default()
                },
            ))
        }
        UserCommand::Import(a) => {
            let text = if a.file.as_os_str() == "-" {
                read_stdin()?
            } else {
                std::fs::read_to_string(&a.file).with_context(|| format!("cannot read {}", a.file.display()))?
            };
            rt.block_on(async {
                let store = open(&a.db).await?;
                match store.import_csv(&text, None).await {
                    Ok(added) => {
                        sayf!("imported {} accounts: {}", added.len(), added.join(", "));
                        Ok(())
                    }
                    Err(stylet_service::store::AccountError::Import(bad)) => {
                        for b in &bad {
                            eprintln!("{}: {b}", a.file.display());
                        }
                        anyhow::bail!("nothing imported: {} bad line(s)", bad.len())
                    }
                    Err(e) => Err(e.into()),
                }
            })
        }
    }
}
