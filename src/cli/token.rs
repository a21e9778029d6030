//! `cellcal token --name NAME --role ROLE`: a new random REST API token, printed once, and the
//! `[[api.tokens]]` entry (name, role, SHA-256 of the token) to paste into the cell configuration.

use anyhow::anyhow;

use cellcal::auth::{new_token, Role, TokenDigest};

use crate::{input, other, Failure};

/// The configuration entry that accepts the token with digest `digest` as `name` with `role`.
pub fn toml_entry(name: &str, role: Role, digest: &TokenDigest) -> String {
    format!(
        "[[api.tokens]]\nname = {}\nrole = \"{role}\"\nsha256 = \"{}\"\n",
        toml::Value::String(name.to_owned()),
        digest.to_hex()
    )
}

/// Make the token and print it (first line, `token: …`) and the TOML to paste.
pub fn run(name: &str, role: &str) -> Result<(), Failure> {
    let role = Role::parse(role).ok_or_else(|| {
        input(anyhow!(
            "--role `{role}`: not one of viewer, technician, operator"
        ))
    })?;
    if name.trim().is_empty() {
        return Err(input(anyhow!("--name must not be empty")));
    }
    let token = new_token().map_err(other)?;
    let entry = toml_entry(name, role, &TokenDigest::of_token(&token));
    println!("token: {token}");
    println!(
        "# paste into the cell configuration (it keeps only the SHA-256; the token is not shown again):"
    );
    print!("{entry}");
    Ok(())
}
