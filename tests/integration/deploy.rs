//! `deploy/compose.yaml` (docs/operations.md "Deploying several replicas"), read without Docker
//! (not on the test machines): it must start what the multi-site set-up needs and say it in
//! flags `stylet serve` has, so that it cannot drift from the binary unnoticed.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use yaml_rust2::{Yaml, YamlLoader};

use crate::common::*;

const REPLICAS: [&str; 3] = ["stylet-1", "stylet-2", "stylet-3"];

fn deploy_file(name: &str) -> String {
    std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy").join(name)).unwrap()
}

/// A mapping with its YAML merge keys (`<<: *anchor`) applied, as Compose reads it.
fn merged(node: &Yaml) -> BTreeMap<String, Yaml> {
    let mut out = BTreeMap::new();
    let Yaml::Hash(map) = node else {
        panic!("not a mapping: {node:?}")
    };
    if let Some(base) = map.get(&Yaml::String("<<".into())) {
        out.extend(merged(base));
    }
    for (k, v) in map {
        if let Some(k) = k.as_str()
            && k != "<<"
        {
            out.insert(k.to_string(), v.clone());
        }
    }
    out
}

fn strings(node: &Yaml) -> Vec<String> {
    node.as_vec()
        .unwrap_or_else(|| panic!("not a list: {node:?}"))
        .iter()
        .map(|v| match v {
            Yaml::String(s) => s.clone(),
            Yaml::Integer(i) => i.to_string(),
            other => panic!("not a string: {other:?}"),
        })
        .collect()
}

/// The value after `flag` in a command line.
fn flag<'a>(command: &'a [String], name: &str) -> &'a str {
    let at = command
        .iter()
        .position(|a| a == name)
        .unwrap_or_else(|| panic!("{name} missing from {command:?}"));
    &command[at + 1]
}

/// The port of `host:port`.
fn port(address: &str) -> &str {
    address.rsplit_once(':').unwrap().1
}

#[test]
fn the_compose_file_starts_postgres_an_object_store_three_replicas_and_a_proxy() {
    let docs = YamlLoader::load_from_str(&deploy_file("compose.yaml")).expect("compose.yaml is YAML");
    let compose = merged(&docs[0]);
    let services = merged(&compose["services"]);
    let volumes: BTreeSet<String> = merged(&compose["volumes"]).into_keys().collect();
    let names: BTreeSet<&str> = services.keys().map(String::as_str).collect();
    for needed in ["postgres", "s3", "bucket", "proxy"].iter().chain(&REPLICAS) {
        assert!(names.contains(needed), "{needed} missing: {names:?}");
    }
    // Whatever a service depends on or mounts is declared.
    for (name, service) in &services {
        let service = merged(service);
        if let Some(deps) = service.get("depends_on") {
            let deps: Vec<String> = match deps {
                Yaml::Array(_) => strings(deps),
                other => merged(other).into_keys().collect(),
            };
            for d in deps {
                assert!(
                    names.contains(d.as_str()),
                    "{name} depends on {d}, which is not a service"
                );
            }
        }
        for mount in service.get("volumes").map(strings).unwrap_or_default() {
            let source = mount.split(':').next().unwrap();
            if !source.starts_with('.') && !source.starts_with('/') {
                assert!(volumes.contains(source), "{name} mounts {source}, not declared");
            }
        }
    }

    // The bucket the replicas use is the one the bucket job makes.
    let made = strings(&merged(&services["bucket"])["command"]).join(" ");
    let bucket = made
        .rsplit("store/")
        .next()
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .to_string();
    let s3 = merged(&services["s3"]);
    let s3_env = merged(&s3["environment"]);

    // Every flag of the replicas' command exists in this build's `stylet serve`.
    let help = ok(&["serve", "--help"]);
    let mut data_volumes = BTreeSet::new();
    let mut database = BTreeSet::new();
    let mut ports = BTreeSet::new();
    for name in REPLICAS {
        let replica = merged(&services[name]);
        let command = strings(&replica["command"]);
        assert_eq!(command[0], "serve", "{name}");
        for arg in command.iter().filter(|a| a.starts_with("--")) {
            assert!(
                help.contains(&format!("{arg} ")) || help.contains(&format!("{arg}\n")),
                "{name}: `stylet serve` has no {arg}"
            );
        }
        // One PostgreSQL database and one store for all; a data directory each.
        let db = flag(&command, "--database");
        assert!(db.starts_with("postgres://") && db.contains("@postgres:5432/"), "{db}");
        database.insert(db.to_string());
        let storage = flag(&command, "--storage");
        assert!(
            storage.starts_with(&format!("s3://{bucket}/")),
            "{storage} is not in bucket {bucket}"
        );
        let data_dir = flag(&command, "--data-dir");
        let mounts = strings(&replica["volumes"]);
        let data = mounts
            .iter()
            .find(|m| m.split(':').nth(1) == Some(data_dir))
            .unwrap_or_else(|| panic!("{name}: nothing mounted at {data_dir}: {mounts:?}"));
        data_volumes.insert(data.split(':').next().unwrap().to_string());
        let atlases = flag(&command, "--atlases");
        assert!(
            mounts.iter().any(|m| m.split(':').nth(1) == Some(atlases)),
            "{name}: {atlases} not mounted"
        );
        ports.insert((
            port(flag(&command, "--bind")).to_string(),
            port(flag(&command, "--admin-bind")).to_string(),
        ));
        // The store's endpoint is the s3 service, with its credentials.
        let env = merged(&replica["environment"]);
        assert!(
            env["AWS_ENDPOINT"].as_str().unwrap().starts_with("http://s3:"),
            "{name}"
        );
        assert_eq!(env["AWS_ACCESS_KEY_ID"], s3_env["MINIO_ROOT_USER"], "{name}");
        assert_eq!(env["AWS_SECRET_ACCESS_KEY"], s3_env["MINIO_ROOT_PASSWORD"], "{name}");
        // Its health check asks the admin port's /readyz; SIGTERM gets time to drain.
        let check = strings(&merged(&replica["healthcheck"])["test"]).join(" ");
        assert!(
            check.contains(&format!(":{}/readyz", port(flag(&command, "--admin-bind")))),
            "{name}: {check}"
        );
        assert!(replica.contains_key("stop_grace_period"), "{name}");
    }
    assert_eq!(
        data_volumes.len(),
        3,
        "each replica has a data directory of its own: {data_volumes:?}"
    );
    assert_eq!(database.len(), 1, "{database:?}");
    assert_eq!(ports.len(), 1, "{ports:?}");
    let (api_port, admin_port) = ports.into_iter().next().unwrap();

    // The proxy balances over the three on their API port and checks their /readyz.
    let caddy = deploy_file("Caddyfile");
    for name in REPLICAS {
        assert!(
            caddy.contains(&format!("{name}:{api_port}")),
            "{name} not behind the proxy"
        );
    }
    assert!(caddy.contains("health_uri /readyz"), "{caddy}");
    assert!(caddy.contains(&format!("health_port {admin_port}")), "{caddy}");
    let proxy = merged(&services["proxy"]);
    assert!(strings(&proxy["volumes"]).iter().any(|m| m.starts_with("./Caddyfile:")));

    // The image has what the health check and the backup use.
    let dockerfile = deploy_file("Dockerfile");
    for needed in ["--bin stylet", "curl", "postgresql-client", "ENTRYPOINT [\"stylet\"]"] {
        assert!(dockerfile.contains(needed), "the Dockerfile lacks {needed}");
    }
}
