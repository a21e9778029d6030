//! `cellcal token --name NAME --role ROLE`: a new random REST API token, printed once, and the
//! `[[api.tokens]]` entry (name, role, SHA-256 of the token) to paste into the cell configuration.

use anyhow::anyhow;

use cellcal::auth::{new_token, Role, TokenDigest};

use super::{input, other, Failure};

/// The configuration entry that accepts the token with digest `digest` as `name` with `role`.
pub fn toml_entry(name: &str, role: Role, digest: &TokenDigest) -> String {
    format!(
        "[[api.tokens]]\nname = {}\nrole = \"{role}\"\nsha256 = \"{}\"\n",
        toml::Value::String(name.to_owned()),
        digest.to_hex()
    )
}

/// Arguments of `cellcal token`.
#[derive(clap::Args)]
pub struct TokenArgs {
    /// Who will hold the token (named in refusals; the token itself is never stored).
    #[arg(long)]
    name: String,
    /// What it may do: `viewer` (reads, abort), `technician` (also answer, pause),
    /// `operator` (everything).
    #[arg(long, value_parser = ["viewer", "technician", "operator"])]
    role: String,
}

/// Make the token and print it (first line, `token: …`) and the TOML to paste.
pub fn run(a: TokenArgs) -> Result<(), Failure> {
    let (name, role) = (a.name.as_str(), a.role.as_str());
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
