//! Replay must give the same bits on every platform (docs/architecture.md "Determinism"). The
//! platform's transcendental functions (`f64::sin`, `atan2`, `powf`, `exp`, …) come from each
//! system's maths library and may differ in the last bit between x86-64 and aarch64, and
//! `mul_add` is one rounding on one machine and two on another when it is emulated; `libm` is the
//! same Rust code everywhere. This test reads the sources of `stylet-physics` and
//! `stylet-scoring` (test modules included: their fixtures feed bit-exact comparisons) and fails on
//! any call of the platform's functions. `sqrt`, `abs`, `floor`, `min`, `clamp`, `to_radians`
//! and the like are exact or a single IEEE operation and stay allowed.

use std::path::{Path, PathBuf};

/// Methods of `f32`/`f64` whose results depend on the platform's maths library or its FMA.
const PLATFORM_MATH: &[&str] = &[
    "sin", "cos", "tan", "sin_cos", "asin", "acos", "atan", "atan2", "sinh", "cosh", "tanh", "asinh", "acosh", "atanh",
    "hypot", "powf", "powi", "exp", "exp2", "exp_m1", "ln", "log", "log2", "log10", "ln_1p", "cbrt", "mul_add",
    "gamma", "ln_gamma",
];

/// One offending call: file, 1-based line and the function.
#[derive(Debug, PartialEq)]
struct Call {
    file: PathBuf,
    line: usize,
    function: String,
}

/// The code of a line without its `//` comment (string literals in physics hold no `//`).
fn code_of(line: &str) -> &str {
    line.find("//").map_or(line, |i| &line[..i])
}

fn is_ident(c: u8) -> bool {
    c.is_ascii_alphanumeric() || c == b'_'
}

/// The platform-math functions a line of code calls, as `x.sin()` or `f64::sin(x)`.
fn platform_calls(code: &str) -> Vec<String> {
    let bytes = code.as_bytes();
    let mut found = Vec::new();
    for (start, _) in code.match_indices(['.', ':']) {
        // `x.name(` or `f64::name` / `f32::name`.
        let name_start = if bytes[start] == b'.' {
            start + 1
        } else if start >= 3
            && bytes.get(start + 1) == Some(&b':')
            && matches!(&bytes[start - 3..start], b"f64" | b"f32")
            && (start == 3 || !is_ident(bytes[start - 4]))
        {
            start + 2
        } else {
            continue;
        };
        let name_end = name_start + bytes[name_start..].iter().take_while(|&&c| is_ident(c)).count();
        let name = &code[name_start..name_end];
        let called = bytes[name_end..].iter().find(|c| !c.is_ascii_whitespace()) == Some(&b'(') || bytes[start] == b':';
        if called && PLATFORM_MATH.contains(&name) {
            found.push(name.to_string());
        }
    }
    found
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let mut entries: Vec<_> = std::fs::read_dir(dir)
        .unwrap_or_else(|e| panic!("reading {}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .collect();
    entries.sort();
    for path in entries {
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

fn platform_math_in(dir: &Path) -> Vec<Call> {
    let mut files = Vec::new();
    rust_files(dir, &mut files);
    assert!(!files.is_empty(), "no Rust sources under {}", dir.display());
    let mut calls = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(&file).unwrap();
        for (i, line) in text.lines().enumerate() {
            for function in platform_calls(code_of(line)) {
                calls.push(Call {
                    file: file.clone(),
                    line: i + 1,
                    function,
                });
            }
        }
    }
    calls
}

#[test]
fn the_scanner_finds_platform_math_and_passes_libm() {
    assert_eq!(platform_calls("let y = x.sin() + (a * b).atan2(c);"), ["sin", "atan2"]);
    assert_eq!(
        platform_calls("let z = f64::hypot(a, b); let w = q.mul_add (r, s);"),
        ["hypot", "mul_add"]
    );
    assert_eq!(
        platform_calls("let p = 10f64.powi(3); let e = t.exp ();"),
        ["powi", "exp"]
    );
    assert!(platform_calls("let y = libm::sin(x) + libm::atan2(a, b) + x.sqrt().abs();").is_empty());
    assert!(platform_calls("let y = self.cos_table[i]; let s = state.log_entries();").is_empty());
    assert!(platform_calls("use std::f64::consts::PI; let f = my_f64::sin;").is_empty());
    assert!(platform_calls(code_of("let y = a; // not x.sin()")).is_empty());
}

#[test]
fn physics_and_scoring_call_libm_not_the_platform_math_library() {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .canonicalize()
        .unwrap();
    let mut calls = platform_math_in(&workspace.join("sim/physics/src"));
    calls.extend(platform_math_in(&workspace.join("scoring/src")));
    let listed: Vec<String> = calls
        .iter()
        .map(|c| {
            let file = c.file.strip_prefix(&workspace).unwrap_or(&c.file);
            format!("{}:{}: {}", file.display(), c.line, c.function)
        })
        .collect();
    assert!(
        calls.is_empty(),
        "platform maths in replayed code (use libm::{{sin, cos, atan2, hypot, pow, exp, log, fma}}, ...):\n{}",
        listed.join("\n")
    );
}
