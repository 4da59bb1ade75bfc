//! The two SQL dialects the store speaks. Queries are written once with SQLite's `?` / `?N`
//! placeholders; on PostgreSQL they are rewritten to `$N` (same numbering rule as SQLite:
//! a bare `?` takes one more than the highest number seen so far). Statements whose SQL
//! differs beyond placeholders branch on [`Backend`] where they are written.

use std::borrow::Cow;

/// Which database a [`super::Store`] talks to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Backend {
    Sqlite,
    Postgres,
}

impl Backend {
    /// The backend a `database_url` names, or None for an unknown scheme.
    pub fn of_url(url: &str) -> Option<Self> {
        if url.starts_with("sqlite:") {
            Some(Backend::Sqlite)
        } else if url.starts_with("postgres://") || url.starts_with("postgresql://") {
            Some(Backend::Postgres)
        } else {
            None
        }
    }

    /// `sql` with its placeholders in this dialect; on PostgreSQL SQLite's
    /// `json_object(` is also spelt `json_build_object(` (same arguments, same result).
    pub fn sql<'a>(&self, sql: impl Into<Cow<'a, str>>) -> Cow<'a, str> {
        let sql = sql.into();
        match self {
            Backend::Sqlite => sql,
            Backend::Postgres => {
                Cow::Owned(dollar_placeholders(&sql).replace("json_object(", "json_build_object("))
            }
        }
    }
}

/// Rewrite `?` and `?N` outside quoted text to `$N`.
fn dollar_placeholders(sql: &str) -> String {
    let mut out = String::with_capacity(sql.len() + 8);
    let mut highest = 0u32;
    let mut chars = sql.chars().peekable();
    let mut quote: Option<char> = None;
    while let Some(c) = chars.next() {
        if let Some(q) = quote {
            out.push(c);
            if c == q {
                quote = None;
            }
            continue;
        }
        match c {
            '\'' | '"' => {
                quote = Some(c);
                out.push(c);
            }
            '?' => {
                let mut digits = String::new();
                while let Some(d) = chars.peek().filter(|d| d.is_ascii_digit()) {
                    digits.push(*d);
                    chars.next();
                }
                let n = match digits.parse::<u32>() {
                    Ok(n) => n,
                    Err(_) => highest + 1,
                };
                highest = highest.max(n);
                out.push('$');
                out.push_str(&n.to_string());
            }
            _ => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn placeholders_follow_sqlite_numbering() {
        let pg = |s: &'static str| Backend::Postgres.sql(s).into_owned();
        assert_eq!(pg("a = ? AND b = ?"), "a = $1 AND b = $2");
        assert_eq!(
            pg("a = ?2 OR b = ?1 OR c = ?"),
            "a = $2 OR b = $1 OR c = $3"
        );
        assert_eq!(
            pg("x = '?' AND y = \"q?\" AND z = ?"),
            "x = '?' AND y = \"q?\" AND z = $1"
        );
        assert_eq!(
            pg("SET e = json_object('a', ?)"),
            "SET e = json_build_object('a', $1)"
        );
        assert_eq!(Backend::Sqlite.sql("a = ?"), "a = ?");
    }

    #[test]
    fn urls_name_their_backend() {
        assert_eq!(Backend::of_url("sqlite://x.db"), Some(Backend::Sqlite));
        assert_eq!(
            Backend::of_url("postgres://u@h/db"),
            Some(Backend::Postgres)
        );
        assert_eq!(
            Backend::of_url("postgresql://u@h/db"),
            Some(Backend::Postgres)
        );
        assert_eq!(Backend::of_url("mysql://h"), None);
    }
}
