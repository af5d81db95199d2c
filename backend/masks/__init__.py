"""Object masks made automatically from the frames and their SfM cameras.

    report = make_masks(frames, sfm, MaskOptions(), emit)   # frame name -> mask, dropped frames

Pipeline, classical by default (no learned model):

1. **Object region** (:mod:`.region`): the orbit's common focus, the point closest to every
   optical axis in the least-squares sense (a camera circling an object keeps it in view), and
   the sparse SfM points near it that fit in the frames. A dominant plane under the focus (the
   table or floor the object stands on) is found by RANSAC and its points are left out. Or the
   user's ``--object-box``, a box in the orbit frame (origin at the focus, Z up, units of the
   orbit radius).
2. **Per-frame segmentation** (:mod:`.segment`): OpenCV GrabCut seeded by the projected region
   (its points' convex hull, widened, as probable foreground), the frame border and the
   observed points off the object as background, the observed object points as foreground.
   With a ground plane, the ground's photo-consistency (:mod:`.ground`: the neighbouring frames
   warped onto the frame through the plane) marks what stands off the ground as sure foreground,
   which colour alone cannot (a shadowed leg the colour of the ground under it). With ``--mask-model FILE.onnx`` a salient-object network read by ``cv2.dnn`` segments
   instead.
3. **Cross-frame consistency** (:mod:`.consistency`): the masks' visual hull on a voxel grid,
   reprojected into every frame and compared with its mask (IoU). Frames that disagree, or
   whose region leaves the frame (the object is cut by the border), are dropped; a second
   GrabCut round seeded by the hull's projection sharpens the rest.
4. **Outline** (:mod:`.outline`): each GrabCut mask's outline is moved onto the frame's own
   edges (a GrabCut round on a 2-pixel band of the unblurred frame, then a colour guided
   filter), leaning to foreground: the hull is cut by every pixel one mask misses.
5. **Trim** (``auto.trim_outside``): a piece of a mask outside the other frames' hull (one of
   them may disagree) that reaches more than 1.25 % of the frame's size beyond it (a shadow, a
   patch of ground the colours did not separate) is cut. Shallower pieces stay, since the
   hull's voxels miss thin parts too.

Why this pipeline: the SfM that the cameras need anyway already separates the object from its
surroundings in 3D (the points the orbit circles against the ground and the far background),
which is the information a single frame lacks; GrabCut turns that sparse, reliable seed into a
dense mask by colour, and the visual hull ties the frames together, so one frame's mistake
shows as a disagreement with all the others instead of a hole in the carved mesh. Nothing has
to be downloaded or trained, and each mask is an ordinary PNG the user can inspect, edit and
import again. A learned model is an option for scenes colour cannot separate, checked the same
way."""

from .auto import MaskOptions, MaskReport, make_masks, parse_object_box

__all__ = ["MaskOptions", "MaskReport", "make_masks", "parse_object_box"]
