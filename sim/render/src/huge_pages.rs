//! Transparent huge pages for the volumes the ray caster reads at random.
//!
//! A frame of the 512 × 512 × 133 chest CT reads its 280 MB of gradient records ([`crate::raycast`])
//! wherever the rays go: with 4 KiB pages nearly every record load also misses the TLB and walks
//! the page table. Linux backs memory with 2 MiB pages where asked to (`madvise(MADV_HUGEPAGE)`;
//! most distributions set `transparent_hugepage` to `madvise`, so nothing is backed unasked), and
//! the soft-tissue frame then takes about 1 % less time (2 % with the whole process on huge
//! pages). A hint only: it changes no value, and where the kernel declines (or elsewhere than
//! Linux) nothing happens.

/// Size of a transparent huge page on x86-64 and most ARM64 kernels.
const HUGE_PAGE_BYTES: usize = 2 << 20;

/// Asks the kernel to back the whole 2 MiB stretches of `memory` with huge pages. Call it before
/// the memory is first written (a fresh `vec![0; n]` of this size is mapped but untouched): pages
/// already backed stay small until the kernel's background collapse. Small slices are left alone.
pub fn advise<T>(memory: &mut [T]) {
    let start = memory.as_mut_ptr() as usize;
    let end = start + std::mem::size_of_val(memory);
    let first = start.next_multiple_of(HUGE_PAGE_BYTES);
    let last = end / HUGE_PAGE_BYTES * HUGE_PAGE_BYTES;
    if last > first {
        advise_range(first, last - first);
    }
}

#[cfg(target_os = "linux")]
fn advise_range(start: usize, len: usize) {
    // SAFETY: [start, start + len) lies inside the caller's slice, which this call borrows
    // mutably; MADV_HUGEPAGE changes how the range is backed, never its contents. A refusal
    // (an older kernel, THP off) returns an error, which changes nothing and is ignored.
    unsafe {
        libc::madvise(start as *mut libc::c_void, len, libc::MADV_HUGEPAGE);
    }
}

#[cfg(not(target_os = "linux"))]
fn advise_range(_start: usize, _len: usize) {}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether the kernel backs `memory` with any huge page: the AnonHugePages of the mapping
    /// that holds it (/proc/self/smaps), or `None` where that cannot be read.
    #[cfg(target_os = "linux")]
    fn huge_kib_of(address: usize) -> Option<u64> {
        let smaps = std::fs::read_to_string("/proc/self/smaps").ok()?;
        let mut inside = false;
        for line in smaps.lines() {
            if let Some((range, _)) = line.split_once(' ')
                && let Some((a, b)) = range.split_once('-')
                && let (Ok(a), Ok(b)) = (usize::from_str_radix(a, 16), usize::from_str_radix(b, 16))
            {
                inside = (a..b).contains(&address);
                continue;
            }
            if inside && let Some(kib) = line.strip_prefix("AnonHugePages:") {
                return kib.trim().trim_end_matches("kB").trim().parse().ok();
            }
        }
        None
    }

    /// The values written after the advice are the values read back, and on a kernel that
    /// honours `madvise` (transparent_hugepage `madvise` or `always`, compaction on an advised
    /// fault) the memory is backed by huge pages.
    #[test]
    fn advised_memory_holds_its_values_and_gets_huge_pages_where_the_kernel_allows() {
        // 48 MiB: above glibc's largest mmap threshold (32 MiB), so the memory is freshly mapped
        // and untouched, as the records are, whatever other tests freed before.
        let n = 24 * HUGE_PAGE_BYTES / 8 + 123;
        let mut v = vec![0u64; n];
        advise(&mut v);
        for (i, x) in v.iter_mut().enumerate() {
            *x = (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        }
        assert!(
            v.iter()
                .enumerate()
                .all(|(i, &x)| x == (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15))
        );
        #[cfg(target_os = "linux")]
        {
            // Backed for sure where madvise is honoured and the kernel compacts memory for an
            // advised fault rather than fall back to small pages.
            let setting = |f: &str| std::fs::read_to_string(format!("/sys/kernel/mm/transparent_hugepage/{f}"));
            let enabled = setting("enabled").unwrap_or_default();
            let defrag = setting("defrag").unwrap_or_default();
            if (enabled.contains("[madvise]") || enabled.contains("[always]"))
                && ["[always]", "[madvise]", "[defer+madvise]"]
                    .iter()
                    .any(|m| defrag.contains(m))
            {
                let kib = huge_kib_of(v.as_ptr() as usize + HUGE_PAGE_BYTES).expect("the mapping in smaps");
                assert!(kib >= 2048, "no huge page backs the advised memory ({kib} KiB)");
            }
        }
        // A slice shorter than a huge page is left alone.
        let mut small = vec![1u8; 4096];
        advise(&mut small);
        assert!(small.iter().all(|&b| b == 1));
    }
}
