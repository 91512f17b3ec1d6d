//! `stylet lti add-platform|add-deployment|list`: the learning management systems Stylet takes LTI 1.3 launches
//! from (docs/integration.md "Launching from a learning management system"), on the service's
//! database (the same store call as the admin page `/admin/lti`; audited with no actor).

use clap::{Args, Subcommand};
use stylet_service::store::NewLtiPlatform;

use super::user::{Db, open, runtime};

#[derive(Debug, Subcommand)]
pub enum LtiCommand {
    /// Register a platform (the values its tool registration shows).
    AddPlatform(AddPlatformArgs),
    /// Add a deployment id to a registered platform (each installation of the tool may have its own).
    AddDeployment(AddDeploymentArgs),
    /// List the registered platforms.
    List(ListArgs),
}

#[derive(Debug, Args)]
pub struct AddDeploymentArgs {
    #[command(flatten)]
    db: Db,
    /// The platform's issuer.
    #[arg(long)]
    issuer: String,
    /// The client id the platform gave Stylet.
    #[arg(long)]
    client_id: String,
    /// The deployment id to add.
    #[arg(long)]
    deployment_id: String,
}

#[derive(Debug, Args)]
pub struct AddPlatformArgs {
    #[command(flatten)]
    db: Db,
    /// The platform's issuer (Moodle: its address; Canvas: https://canvas.instructure.com).
    #[arg(long)]
    issuer: String,
    /// The client id the platform gave Stylet.
    #[arg(long)]
    client_id: String,
    /// A deployment id (repeat for several).
    #[arg(long = "deployment-id", required = true)]
    deployment_ids: Vec<String>,
    /// The platform's public keyset URL (JWKS).
    #[arg(long)]
    keyset_url: String,
    /// The platform's authentication request URL (OIDC).
    #[arg(long)]
    auth_url: String,
    /// The platform's access token URL (OAuth 2, for grades).
    #[arg(long)]
    token_url: String,
    /// An LTI role that makes an instructor (repeat for several; default Instructor,
    /// TeachingAssistant, ContentDeveloper). Learner makes a trainee.
    #[arg(long = "instructor-role")]
    instructor_roles: Vec<String>,
}

#[derive(Debug, Args)]
pub struct ListArgs {
    #[command(flatten)]
    db: Db,
}

pub fn run(cmd: LtiCommand) -> anyhow::Result<()> {
    runtime()?.block_on(async {
        match cmd {
            LtiCommand::AddPlatform(a) => {
                let new = NewLtiPlatform {
                    issuer: a.issuer,
                    client_id: a.client_id,
                    deployment_ids: a.deployment_ids,
                    keyset_url: a.keyset_url,
                    auth_url: a.auth_url,
                    token_url: a.token_url,
                    instructor_roles: a.instructor_roles,
                };
                let problems = new.check();
                if !problems.is_empty() {
                    anyhow::bail!("not registered: {}", problems.join("; "));
                }
                let p = open(&a.db).await?.add_lti_platform(&new, None).await?;
                sayf!("registered {} (client id {}) as {}", p.issuer, p.client_id, p.id);
                Ok(())
            }
            LtiCommand::AddDeployment(a) => {
                let store = open(&a.db).await?;
                let Some(platform) = store.lti_platforms_of(&a.issuer, Some(&a.client_id)).await?.pop() else {
                    anyhow::bail!(
                        "no platform with issuer {} and client id {} is registered",
                        a.issuer,
                        a.client_id
                    );
                };
                let p = store
                    .add_lti_deployment(&platform.id, &a.deployment_id, None)
                    .await?
                    .ok_or_else(|| anyhow::anyhow!("the platform was removed meanwhile"))?;
                sayf!("{}: deployments {}", p.issuer, p.deployment_ids.join(","));
                Ok(())
            }
            LtiCommand::List(a) => {
                for p in open(&a.db).await?.lti_platforms().await? {
                    sayf!(
                        "{}  {}  client id {}  deployments {}  instructor roles {}",
                        p.id,
                        p.issuer,
                        p.client_id,
                        p.deployment_ids.join(","),
                        p.instructor_roles.join(",")
                    );
                }
                Ok(())
            }
        }
    })
}
