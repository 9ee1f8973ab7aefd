//! The AWS shared config files (`~/.aws/credentials`, `~/.aws/config`) for the S3 client, which
//! `object_store` does not read: when no `AWS_ACCESS_KEY_ID` is in the environment, the static keys,
//! region and `endpoint_url` of the profile `AWS_PROFILE` (default `default`) are used. Variables win
//! over the files; SSO and assume-role profiles are not resolved (export their credentials instead).

use crate::error::{Error, Result};
use object_store::aws::{AmazonS3Builder, AmazonS3ConfigKey};
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Sections of an INI file: name → key → value.
pub type Ini = BTreeMap<String, BTreeMap<String, String>>;

/// Parses the INI dialect of the AWS files: `[section]`, `key = value`, `#` and `;` comments.
pub fn parse_ini(text: &str) -> Ini {
    let mut out = Ini::new();
    let mut section: Option<String> = None;
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') || line.starts_with(';') {
            continue;
        }
        if let Some(name) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            section = Some(name.trim().to_string());
            out.entry(name.trim().to_string()).or_default();
        } else if let (Some(s), Some((k, v))) = (&section, line.split_once('=')) {
            out.entry(s.clone()).or_default().insert(k.trim().to_ascii_lowercase(), v.trim().to_string());
        }
    }
    out
}

/// The settings of `profile` from the credentials and config files' texts: keys first from the
/// credentials file, then from the config file's `[profile <name>]` (`[default]` for the default).
pub fn profile_settings(profile: &str, credentials: &str, config: &str) -> Option<BTreeMap<String, String>> {
    let creds = parse_ini(credentials);
    let conf = parse_ini(config);
    let conf_section = if profile == "default" { "default".to_string() } else { format!("profile {profile}") };
    let mut found = None::<BTreeMap<String, String>>;
    for section in [conf.get(&conf_section), creds.get(profile)].into_iter().flatten() {
        found.get_or_insert_with(BTreeMap::new).extend(section.clone());
    }
    found
}

fn env(key: &str) -> Option<String> {
    std::env::var(key).ok().filter(|v| !v.trim().is_empty())
}

fn home_file(var: &str, name: &str) -> Option<PathBuf> {
    env(var).map(PathBuf::from).or_else(|| env("HOME").map(|h| PathBuf::from(h).join(".aws").join(name)))
}

/// Adds the profile's keys, region and endpoint to `builder` unless the environment has them.
pub fn apply(mut builder: AmazonS3Builder) -> Result<AmazonS3Builder> {
    if env("AWS_ACCESS_KEY_ID").is_some() {
        return Ok(builder);
    }
    let explicit = env("AWS_PROFILE").or_else(|| env("AWS_DEFAULT_PROFILE"));
    let profile = explicit.clone().unwrap_or_else(|| "default".into());
    let read = |p: Option<PathBuf>| p.and_then(|p| std::fs::read_to_string(p).ok()).unwrap_or_default();
    let creds_path = home_file("AWS_SHARED_CREDENTIALS_FILE", "credentials");
    let settings = profile_settings(&profile, &read(creds_path.clone()), &read(home_file("AWS_CONFIG_FILE", "config")));
    let Some(settings) = settings else {
        return match explicit {
            Some(p) => Err(Error::config(
                "AWS_PROFILE",
                format!("profile `{p}` is in neither {} nor the AWS config file", creds_path.unwrap_or_default().display()),
            )),
            None => Ok(builder),
        };
    };
    match (settings.get("aws_access_key_id"), settings.get("aws_secret_access_key")) {
        (Some(id), Some(secret)) => {
            builder = builder.with_access_key_id(id).with_secret_access_key(secret);
            if let Some(token) = settings.get("aws_session_token") {
                builder = builder.with_token(token);
            }
        }
        _ if explicit.is_some() => {
            return Err(Error::config(
                "AWS_PROFILE",
                format!(
                    "profile `{profile}` has no aws_access_key_id / aws_secret_access_key (SSO and assume-role profiles are \
                     not read: export the credentials, e.g. eval \"$(aws configure export-credentials --format env)\")"
                ),
            ))
        }
        _ => {}
    }
    if env("AWS_REGION").is_none() && env("AWS_DEFAULT_REGION").is_none() {
        if let Some(region) = settings.get("region") {
            builder = builder.with_region(region);
        }
    }
    if builder.get_config_value(&AmazonS3ConfigKey::Endpoint).is_none() {
        if let Some(endpoint) = settings.get("endpoint_url") {
            builder = builder.with_endpoint(endpoint);
        }
    }
    Ok(builder)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn profiles_merge_credentials_over_config() {
        let creds = "[default]\naws_access_key_id = AK1\naws_secret_access_key = S1\n\n[dev]\n# comment\naws_access_key_id=AK2\naws_secret_access_key = S2\naws_session_token = T2\n";
        let config = "[default]\nregion = eu-west-1\n[profile dev]\nregion = us-east-2\nendpoint_url = http://127.0.0.1:9000\naws_access_key_id = ignored\n";
        let d = profile_settings("default", creds, config).unwrap();
        assert_eq!((d["aws_access_key_id"].as_str(), d["region"].as_str()), ("AK1", "eu-west-1"));
        let dev = profile_settings("dev", creds, config).unwrap();
        assert_eq!(dev["aws_access_key_id"], "AK2", "the credentials file wins over the config file");
        assert_eq!((dev["aws_session_token"].as_str(), dev["endpoint_url"].as_str()), ("T2", "http://127.0.0.1:9000"));
        assert!(profile_settings("none", creds, config).is_none());
        assert_eq!(parse_ini("key = outside\n[a]\n; c\nK = v = w\n")["a"]["k"], "v = w");
    }
}
