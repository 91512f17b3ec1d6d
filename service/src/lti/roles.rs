//! LTI roles to Stylet roles (docs/integration.md "Roles"). A launch whose roles include one of
//! the platform's instructor roles (by default `Instructor`, `TeachingAssistant` and
//! `ContentDeveloper`, set per platform at registration) makes an instructor; else `Learner`
//! makes a trainee; anything else (a guest, an observer, a mentor) is refused. The role is the
//! account's from its first launch on (see `Store::provision_lti_user`); a launch never makes
//! curriculum staff or an admin: those accounts are made in Stylet.
//!
//! Role values are URIs (LTI 1.3 core §A.2): context roles
//! `http://purl.imsglobal.org/vocab/lis/v2/membership#Instructor`, sub-roles
//! `…/membership/Instructor#TeachingAssistant`, institution and system roles in their own
//! vocabularies; LTI 1.3 also allows the short name alone for a context role. A configured role
//! matches a value equal to it, the context role of that short name, or a sub-role whose parent
//! it is (a sub-role matches its own name only when configured as `Role#SubRole`).

use crate::store::Role;

const MEMBERSHIP: &str = "http://purl.imsglobal.org/vocab/lis/v2/membership";

/// Whether the launch value `value` is the configured role `configured`.
fn is(value: &str, configured: &str) -> bool {
    if value == configured {
        return true;
    }
    // `…/membership#Role`, or a sub-role `…/membership/Role#SubRole`, which is its parent role
    // (`Learner#Instructor` is a learner) unless `Role#SubRole` itself is configured.
    match value.strip_prefix(MEMBERSHIP) {
        Some(rest) => match (rest.strip_prefix('#'), rest.strip_prefix('/')) {
            (Some(role), _) => role == configured,
            (_, Some(sub)) => sub == configured || sub.split('#').next() == Some(configured),
            _ => false,
        },
        None => false,
    }
}

/// The Stylet role of a launch with `roles`, given the platform's instructor roles; None when no
/// role is one Stylet gives.
pub fn stylet_role(roles: &[String], instructor_roles: &[String]) -> Option<Role> {
    if roles.iter().any(|v| instructor_roles.iter().any(|c| is(v, c))) {
        return Some(Role::Instructor);
    }
    roles.iter().any(|v| is(v, "Learner")).then_some(Role::Trainee)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn defaults() -> Vec<String> {
        crate::store::DEFAULT_INSTRUCTOR_ROLES
            .iter()
            .map(|s| s.to_string())
            .collect()
    }

    fn v(roles: &[&str]) -> Vec<String> {
        roles.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn lti_roles_map_to_stylet_roles() {
        let d = defaults();
        let m = |r: &str| format!("{MEMBERSHIP}#{r}");
        assert_eq!(stylet_role(&v(&[&m("Learner")]), &d), Some(Role::Trainee));
        assert_eq!(stylet_role(&v(&[&m("Instructor")]), &d), Some(Role::Instructor));
        assert_eq!(stylet_role(&v(&["Learner"]), &d), Some(Role::Trainee), "short names");
        // A sub-role is its parent role: a learner's "instructor" sub-role is a learner.
        assert_eq!(
            stylet_role(&v(&[&format!("{MEMBERSHIP}/Learner#Instructor")]), &d),
            Some(Role::Trainee)
        );
        assert_eq!(
            stylet_role(
                &v(&[&format!("{MEMBERSHIP}/Learner#Instructor")]),
                &v(&["Learner#Instructor"])
            ),
            Some(Role::Instructor),
            "unless configured so"
        );
        // A sub-role of an instructor, and an instructor who is a learner too.
        assert_eq!(
            stylet_role(&v(&[&format!("{MEMBERSHIP}/Instructor#TeachingAssistant")]), &d),
            Some(Role::Instructor)
        );
        assert_eq!(
            stylet_role(&v(&[&m("Learner"), &m("Instructor")]), &d),
            Some(Role::Instructor)
        );
        // Institution administrators are not context instructors; guests get nothing.
        assert_eq!(
            stylet_role(
                &v(&["http://purl.imsglobal.org/vocab/lis/v2/institution/person#Administrator"]),
                &d
            ),
            None
        );
        assert_eq!(stylet_role(&v(&[&m("Mentor")]), &d), None);
        assert_eq!(stylet_role(&[], &d), None);
        // Configured: mentors teach here.
        assert_eq!(
            stylet_role(&v(&[&m("Mentor")]), &v(&["Mentor"])),
            Some(Role::Instructor)
        );
        // A lookalike vocabulary is not the membership one.
        assert_eq!(
            stylet_role(&v(&["http://evil.example/membership#Instructor"]), &d),
            None
        );
        assert_eq!(stylet_role(&v(&[&format!("{MEMBERSHIP}X#Instructor")]), &d), None);
    }
}
