#![no_main]
//! Fuzz target: see fuzz/harness/ros2_bag.rs.
#[path = "../harness/ros2_bag.rs"]
mod harness;
#[path = "../harness/scratch.rs"]
mod scratch;
#[path = "../harness/tiny_frame.rs"]
mod tiny_frame;

libfuzzer_sys::fuzz_target!(
    // libFuzzer's panic hook aborts before any unwinding, so it would report the
    // panic inside the `mcap` reader that `McapBag` catches and turns into the bag's
    // error (fuzz/regressions/ros2_bag/record-overruns-uncompressed-chunk.mcap) as a
    // crash. Panics raised in the mcap crate's own source unwind to that catch; every
    // other panic still goes to libFuzzer's hook and aborts.
    init: {
        let libfuzzer_hook = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            let in_mcap = info.location().is_some_and(|l| {
                let file = l.file().replace('\\', "/");
                file.contains("/mcap-") && !file.contains("/tricons")
            });
            if !in_mcap {
                libfuzzer_hook(info);
            }
        }));
    },
    |data: &[u8]| harness::run(data)
);
