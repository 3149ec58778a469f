//! Where the flash goes: the function symbols of a Cortex-M image (ELF32 `.symtab`), their
//! sizes, demangled and grouped by module, for the bench report. Read from the ELF directly
//! (no `nm` needed); a symbol's size is what the linker kept (after LTO and inlining: an
//! inlined callee counts in its caller).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// One function of the image: demangled name (hash dropped) and size in bytes.
#[derive(Debug, Clone)]
pub struct Symbol {
    pub name: String,
    pub bytes: u64,
}

/// The function symbols (`STT_FUNC`, size > 0) of an ELF32 little-endian image, one per
/// address (aliases such as `__aeabi_memcpy4` / `memcpy` counted once), largest first.
pub fn functions(elf: &Path) -> Result<Vec<Symbol>, String> {
    let b = std::fs::read(elf).map_err(|e| format!("{}: {e}", elf.display()))?;
    let bad = || format!("{}: not a little-endian ELF32 image", elf.display());
    let u16_at = |o: usize| {
        b.get(o..o + 2)
            .map(|s| u16::from_le_bytes([s[0], s[1]]) as usize)
    };
    let u32_at = |o: usize| {
        b.get(o..o + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]) as usize)
    };
    let c_str = |at: usize| -> Option<String> {
        let s = b.get(at..)?;
        let end = s.iter().position(|&c| c == 0)?;
        Some(String::from_utf8_lossy(&s[..end]).into_owned())
    };
    if b.get(0..6) != Some(&[0x7f, b'E', b'L', b'F', 1, 1][..]) {
        return Err(bad());
    }
    let shoff = u32_at(0x20).ok_or_else(bad)?;
    let shentsize = u16_at(0x2e).ok_or_else(bad)?;
    let shnum = u16_at(0x30).ok_or_else(bad)?;
    let section = |i: usize| shoff + i * shentsize;
    // The symbol table (SHT_SYMTAB = 2) and its string table (sh_link).
    let symtab = (0..shnum)
        .map(section)
        .find(|&h| u32_at(h + 4) == Some(2))
        .ok_or_else(|| format!("{}: no symbol table", elf.display()))?;
    let sym_off = u32_at(symtab + 0x10).ok_or_else(bad)?;
    let sym_size = u32_at(symtab + 0x14).ok_or_else(bad)?;
    let link = u32_at(symtab + 0x18).ok_or_else(bad)?;
    let str_off = u32_at(section(link) + 0x10).ok_or_else(bad)?;
    let mut by_addr: BTreeMap<usize, Symbol> = BTreeMap::new();
    for e in (sym_off..sym_off + sym_size).step_by(16) {
        let name_off = u32_at(e).ok_or_else(bad)?;
        // Thumb functions have bit 0 of the address set.
        let addr = u32_at(e + 4).ok_or_else(bad)? & !1;
        let size = u32_at(e + 8).ok_or_else(bad)? as u64;
        let info = *b.get(e + 12).ok_or_else(bad)?;
        if info & 0xf != 2 || size == 0 {
            continue; // not STT_FUNC
        }
        let name = demangle(&c_str(str_off + name_off).ok_or_else(bad)?);
        by_addr.entry(addr).or_insert(Symbol { name, bytes: size });
    }
    let mut out: Vec<Symbol> = by_addr.into_values().collect();
    out.sort_by(|a, b| b.bytes.cmp(&a.bytes).then(a.name.cmp(&b.name)));
    Ok(out)
}

/// Rust's legacy mangling (`_ZN…E`, the `h<hash>` component dropped) to a readable path;
/// other names as they are.
pub fn demangle(sym: &str) -> String {
    if let Some(v0) = sym.strip_prefix("_R") {
        return demangle_v0_path(v0).unwrap_or_else(|| sym.to_string());
    }
    let Some(mut rest) = sym.strip_prefix("_ZN") else {
        return sym.to_string();
    };
    let mut parts = Vec::new();
    while let Some(len_end) = rest.find(|c: char| !c.is_ascii_digit()) {
        if len_end == 0 {
            break;
        }
        let Ok(len) = rest[..len_end].parse::<usize>() else {
            break;
        };
        let Some(part) = rest.get(len_end..len_end + len) else {
            break;
        };
        parts.push(part);
        rest = &rest[len_end + len..];
    }
    if let Some(last) = parts.last() {
        if last.len() == 17
            && last.starts_with('h')
            && last[1..].chars().all(|c| c.is_ascii_hexdigit())
        {
            parts.pop();
        }
    }
    let joined: Vec<String> = parts
        .iter()
        .map(|p| {
            let p = p
                .strip_prefix("_$")
                .map_or(p.to_string(), |s| format!("${s}"));
            let mut s = p
                .replace("$LT$", "<")
                .replace("$GT$", ">")
                .replace("$u20$", " ")
                .replace("$C$", ",")
                .replace("$RF$", "&")
                .replace("$BP$", "*")
                .replace("$SP$", "@")
                .replace("$u27$", "'")
                .replace("$u5b$", "[")
                .replace("$u5d$", "]")
                .replace("$u7b$", "{")
                .replace("$u7d$", "}")
                .replace("$u3b$", ";")
                .replace("$u2b$", "+")
                .replace("$u22$", "\"");
            s = s.replace("..", "::");
            s
        })
        .collect();
    joined.join("::")
}

/// The identifiers of a v0-mangled plain path (`_R` already stripped; how the precompiled
/// `compiler_builtins` is mangled), joined with `::`: each `<decimal length>[_]<ident>`, the
/// crate disambiguator (`Cs<base62>_`) skipped. `None` when no identifier is found.
fn demangle_v0_path(v0: &str) -> Option<String> {
    let b = v0.as_bytes();
    let mut parts = Vec::new();
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'C' && b.get(i + 1) == Some(&b's') {
            // Crate root with a disambiguator: skip `s<base62>_`.
            i += 2;
            while i < b.len() && b[i] != b'_' {
                i += 1;
            }
            i += 1;
            continue;
        }
        if b[i].is_ascii_digit() {
            let start = i;
            while i < b.len() && b[i].is_ascii_digit() {
                i += 1;
            }
            let n: usize = v0[start..i].parse().ok()?;
            if b.get(i) == Some(&b'_') {
                i += 1;
            }
            let ident = v0.get(i..i + n)?;
            parts.push(ident);
            i += n;
            continue;
        }
        i += 1;
    }
    (!parts.is_empty()).then(|| parts.join("::"))
}

/// The group a function's bytes are charged to: `nav_core::<module>` for nav-core (the first
/// nav-core path in the name, so `<Filter as Estimator>::from_design` counts in the filter's
/// module), the f64 soft-float routines on their own (an f32 flight image should need few),
/// then the crate.
pub fn group(name: &str) -> String {
    if let Some(at) = name.find("nav_core::") {
        let tail = &name[at + "nav_core::".len()..];
        let module: String = tail
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        return format!("nav_core::{module}");
    }
    let f64_soft = [
        "adddf3",
        "subdf3",
        "muldf3",
        "divdf3",
        "dadd",
        "dsub",
        "dmul",
        "ddiv",
        "d2f",
        "f2d",
        "dcmp",
        "d2ulz",
        "d2lz",
        "ul2d",
        "l2d",
        "i2d",
        "ui2d",
        "d2iz",
        "d2uiz",
        "extendsfdf2",
        "truncdfsf2",
        "fixdf",
        "floatundidf",
        "floatdidf",
        "floatsidf",
        "floatunsidf",
        "cmpdf2",
        "gedf2",
        "ledf2",
        "unorddf2",
    ];
    let base = name.rsplit("::").next().unwrap_or(name);
    if (base.starts_with("__") || name.starts_with("compiler_builtins::float"))
        && f64_soft.iter().any(|s| base.contains(s))
    {
        return "f64 soft float (compiler_builtins)".into();
    }
    if base.starts_with("__aeabi")
        || base.starts_with("mem")
        || base.starts_with("udiv")
        || name.starts_with("compiler_builtins")
    {
        return "compiler_builtins (memcpy, integer division, …)".into();
    }
    let krate: String = name
        .trim_start_matches(['_', '<', '$'])
        .chars()
        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
        .collect();
    match krate.as_str() {
        "nav_size" | "nav_firmware" | "nav_golden" => {
            "the image's own code (flight loop, with what it inlined)".into()
        }
        k if k.starts_with("defmt") => "defmt (logger)".into(),
        "fminf" | "fmaxf" | "sqrtf" | "fabsf" => "libm".into(),
        k if name.contains("::") => k.to_string(),
        _ => "runtime (reset, exception handlers, main)".into(),
    }
}

/// `cargo xtask flash [ELF]`: prints [`table`] for `elf` (default: the flight image `nav-size`
/// of the last firmware build).
pub fn print(elf: Option<PathBuf>) -> Result<(), String> {
    let elf = elf.unwrap_or_else(|| {
        crate::root().join("tests/firmware/target/thumbv7em-none-eabihf/release/nav-size")
    });
    let (text, _, _, _) = crate::firmware::section_sizes(&elf)?;
    let label = elf
        .file_name()
        .map_or_else(|| "image".into(), |n| n.to_string_lossy().into_owned());
    println!("{}", table(&label, &functions(&elf)?, text, 40));
    Ok(())
}

/// Markdown "where the flash goes" for an image: bytes per group, then the `top` largest
/// functions. `text_bytes` is the image's `.text` (the functions' sum differs by alignment
/// padding and the vector table).
pub fn table(label: &str, syms: &[Symbol], text_bytes: u64, top: usize) -> String {
    let mut groups: BTreeMap<String, (u64, usize)> = BTreeMap::new();
    for s in syms {
        let g = groups.entry(group(&s.name)).or_default();
        g.0 += s.bytes;
        g.1 += 1;
    }
    let mut groups: Vec<_> = groups.into_iter().collect();
    groups.sort_by(|a, b| b.1 .0.cmp(&a.1 .0).then(a.0.cmp(&b.0)));
    let total: u64 = syms.iter().map(|s| s.bytes).sum();
    let pct = |b: u64| 100.0 * b as f64 / text_bytes.max(1) as f64;
    let mut md = format!(
        "\n### Where the flash goes: `{label}` (`.text` {text_bytes} B)\n\n\
         Function symbols of the linked image (after LTO: an inlined callee counts in its \
         caller), generated by `cargo xtask bench`; functions sum to {total} B, the rest is \
         alignment and the vector table.\n\n\
         | module | functions | bytes | % of `.text` |\n| --- | --- | --- | --- |\n"
    );
    for (name, (bytes, n)) in &groups {
        md.push_str(&format!(
            "| `{name}` | {n} | {bytes} | {:.1} |\n",
            pct(*bytes)
        ));
    }
    md.push_str(&format!(
        "\n| largest functions of `{label}` | bytes | % of `.text` |\n| --- | --- | --- |\n"
    ));
    for s in syms.iter().take(top) {
        let name = if s.name.chars().count() > 140 {
            let short: String = s.name.chars().take(137).collect();
            format!("{short}…")
        } else {
            s.name.clone()
        };
        md.push_str(&format!(
            "| `{}` | {} | {:.1} |\n",
            name.replace('|', "\\|"),
            s.bytes,
            pct(s.bytes)
        ));
    }
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn demangles_legacy_paths() {
        assert_eq!(
            demangle("_ZN8nav_core10seeker_ins9generated9predict1718propagate_in_place17h3977c67187de125cE"),
            "nav_core::seeker_ins::generated::predict17::propagate_in_place"
        );
        assert_eq!(
            demangle("_ZN122_$LT$nav_core..transfer_alignment..filter..TransferAlignment$LT$T$C$_$C$_$GT$$u20$as$u20$nav_core..contract..Estimator$GT$12reinitialise17h95e5a25321a00352E"),
            "<nav_core::transfer_alignment::filter::TransferAlignment<T,_,_> as nav_core::contract::Estimator>::reinitialise"
        );
        assert_eq!(demangle("__aeabi_d2f"), "__aeabi_d2f");
        assert_eq!(
            demangle("_RNvNtNtCs7NhdfSRABLd_17compiler_builtins5float3div8___divdf3"),
            "compiler_builtins::float::div::__divdf3"
        );
    }

    #[test]
    fn groups() {
        assert_eq!(
            group("<nav_core::seeker_ins::filter::SeekerIns<T> as nav_core::contract::Estimator>::reinitialise"),
            "nav_core::seeker_ins"
        );
        assert_eq!(
            group("compiler_builtins::float::div::__divdf3"),
            "f64 soft float (compiler_builtins)"
        );
        assert_eq!(group("__aeabi_d2f"), "f64 soft float (compiler_builtins)");
        assert_eq!(
            group("compiler_builtins::mem::memcpy"),
            "compiler_builtins (memcpy, integer division, …)"
        );
        assert_eq!(group("libm::math::sqrtf::sqrtf"), "libm");
    }
}
