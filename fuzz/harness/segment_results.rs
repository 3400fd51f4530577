//! Published Mask R-CNN result pickles (`tricons replay --masks results:DIR`): numpy
//! arrays inside Python pickles, any protocol.

/// One input; errors are fine, panics, aborts and hangs are the bugs.
pub fn run(data: &[u8]) {
    let path = crate::scratch::file("results_test_scene_1_0000.pkl", data);
    // the seeds are 8x6 images; other sizes exercise the shape checks
    for (w, h) in [(8, 6), (6, 8), (0, 0)] {
        let _ = tricons::segment::published::PublishedDetections::read(&path, w, h);
    }
}
