#!/usr/bin/env python3
"""Build the tiny ONNX graphs that stand in for user-supplied YOLO and SAM exports in tests.

They have the same input/output names, shapes and metadata as the real exports but compute
something simple and predictable from their inputs, so the Rust tests can check our pre- and
post-processing numerically. Run once in a throwaway venv with `onnx` and `numpy`:

    python3 -m venv /tmp/onnxvenv && /tmp/onnxvenv/bin/pip install onnx numpy
    /tmp/onnxvenv/bin/python scripts/make_vision_fixtures.py tests/fixtures/vision
"""
import sys
import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = [helper.make_opsetid("", 17)]


def save(model, path):
    onnx.checker.check_model(model)
    onnx.save(model, path)
    print("wrote", path)


def yolo(out_dir):
    """Ultralytics-style detect export: images [1,3,64,64] -> output0 [1, 4+nc, 8].

    Boxes are constants (cx, cy, w, h in letterboxed input pixels); the score of class c at
    anchor k is one input pixel, chosen by PIX[k][c] = (channel, y, x), so the test can tell
    from the scores whether the letterbox (scale, padding value 114, centring, /255) is right.
    """
    size, nc, anchors = 64, 3, 8
    boxes = np.zeros((4, anchors), np.float32)
    # anchor 0: box (16,24)-(48,40); anchor 1: (4,20)-(20,44); anchor 2: (40,18)-(60,30)
    # anchor 3: near-duplicate of anchor 0 with a lower score (must be suppressed by NMS)
    corners = [(16, 24, 48, 40), (4, 20, 20, 44), (40, 18, 60, 30), (17, 24, 48, 41)]
    for k in range(anchors):
        x1, y1, x2, y2 = corners[k] if k < len(corners) else (0, 0, 8, 8)
        boxes[:, k] = [(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1]
    # the test image is 128x64: left half red, right half blue -> letterboxed to rows 16..48
    inside_left, inside_right, pad = (32, 10), (32, 50), (2, 10)
    R, G, B = 0, 1, 2
    pix = [
        [(R, *inside_left), (B, *inside_left), (G, *pad)],   # person 1.0
        [(R, *inside_right), (B, *inside_right), (G, *inside_right)],  # chair 1.0
        [(R, *inside_right), (G, *inside_right), (R, *pad)],  # sofa 114/255
        [(R, *pad), (G, *inside_left), (G, *inside_right)],  # person 0.447, dup of 0
    ] + [[(G, *inside_left)] * nc] * (anchors - 4)
    idx = np.array([[c * size * size + y * size + x for (c, y, x) in row] for row in pix], np.int64).T  # [nc, A]

    nodes = [
        helper.make_node("Reshape", ["images", "flat_shape"], ["flat"]),
        helper.make_node("Gather", ["flat", "idx"], ["scores"], axis=1),  # [1, nc, A]
        helper.make_node("Concat", ["boxes", "scores"], ["output0"], axis=1),
    ]
    inits = [
        numpy_helper.from_array(np.array([1, -1], np.int64), "flat_shape"),
        numpy_helper.from_array(idx, "idx"),
        numpy_helper.from_array(boxes[None], "boxes"),
    ]
    graph = helper.make_graph(
        nodes, "yolo_signature",
        [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, size, size])],
        [helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, 4 + nc, anchors])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=OPSET, producer_name="grounder-fixtures")
    model.ir_version = 8
    meta = {
        "names": "{0: 'person', 1: 'chair', 2: 'sofa'}",
        "imgsz": "[64, 64]",
        "stride": "32",
        "task": "detect",
        "description": "signature fixture for an Ultralytics YOLO detect export",
    }
    for k, v in meta.items():
        model.metadata_props.append(onnx.StringStringEntryProto(key=k, value=v))
    save(model, f"{out_dir}/yolo-signature.onnx")


def sam_encoder(out_dir):
    """input_image [1,3,1024,1024] -> image_embeddings [1,256,64,64] (16x16 mean, 1x1 conv)."""
    w = np.zeros((256, 3, 1, 1), np.float32)
    for k in range(256):
        w[k, k % 3, 0, 0] = 1.0
    nodes = [
        helper.make_node("AveragePool", ["input_image"], ["pooled"], kernel_shape=[16, 16], strides=[16, 16]),
        helper.make_node("Conv", ["pooled", "w"], ["image_embeddings"]),
    ]
    graph = helper.make_graph(
        nodes, "sam_encoder_signature",
        [helper.make_tensor_value_info("input_image", TensorProto.FLOAT, [1, 3, 1024, 1024])],
        [helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64])],
        [numpy_helper.from_array(w, "w")],
    )
    model = helper.make_model(graph, opset_imports=OPSET, producer_name="grounder-fixtures")
    model.ir_version = 8
    save(model, f"{out_dir}/sam-encoder-signature.onnx")


def sam_decoder(out_dir):
    """The decoder signature of segment-anything's ONNX export, with 3 candidate masks.

    The box arrives as two corner points (labels 2 and 3) in the 1024-long-side frame. The
    graph maps it back to original pixels with s = 1024 / max(H, W) and returns, at
    orig_im_size, mask logits: 0 = box shrunk by 4 px, 1 = the box, 2 = everything.
    iou_predictions = [0.6, 0.1 * (l0 + l1) + 0.3, 0.5 + 0 * mean(embeddings)], so the box
    mask wins only when the labels are 2 and 3.
    """
    c = lambda name, arr: numpy_helper.from_array(np.asarray(arr), name)
    n = helper.make_node
    nodes = [
        # scale s = 1024 / max(H, W); corners in original pixels
        n("ReduceMax", ["orig_im_size"], ["maxside"], keepdims=1),
        n("Div", ["c1024", "maxside"], ["s"]),
        n("Div", ["point_coords", "s"], ["pts"]),  # [1,2,2]
        n("Gather", ["pts", "i0"], ["p0"], axis=1),  # [1,2]
        n("Gather", ["pts", "i1"], ["p1"], axis=1),
        n("Gather", ["p0", "i0"], ["x1"], axis=1),  # [1]
        n("Gather", ["p0", "i1"], ["y1"], axis=1),
        n("Gather", ["p1", "i0"], ["x2"], axis=1),
        n("Gather", ["p1", "i1"], ["y2"], axis=1),
        # pixel grids from orig_im_size (pixel centres at +0.5)
        n("Gather", ["orig_im_size", "i0s"], ["Hf"]),
        n("Gather", ["orig_im_size", "i1s"], ["Wf"]),
        n("Range", ["f0", "Hf", "f1"], ["ys0"]),
        n("Range", ["f0", "Wf", "f1"], ["xs0"]),
        n("Add", ["ys0", "half"], ["ys1"]),
        n("Add", ["xs0", "half"], ["xs"]),
        n("Unsqueeze", ["ys1", "ax1"], ["ys"]),  # [H,1]
        n("Sub", ["xs", "x1"], ["dl"]),
        n("Sub", ["x2", "xs"], ["dr"]),
        n("Sub", ["ys", "y1"], ["dt"]),
        n("Sub", ["y2", "ys"], ["db"]),
        n("Min", ["dl", "dr"], ["dx"]),  # [W]
        n("Min", ["dt", "db"], ["dy"]),  # [H,1]
        n("Min", ["dx", "dy"], ["box"]),  # [H,W]
        n("Sub", ["box", "f4"], ["shrunk"]),
        n("Mul", ["box", "f0"], ["zeros"]),
        n("Add", ["zeros", "f1"], ["ones"]),
        n("Unsqueeze", ["shrunk", "ax0"], ["m0"]),
        n("Unsqueeze", ["box", "ax0"], ["m1"]),
        n("Unsqueeze", ["ones", "ax0"], ["m2"]),
        n("Concat", ["m0", "m1", "m2"], ["m"], axis=0),
        n("Unsqueeze", ["m", "ax0"], ["masks"]),  # [1,3,H,W]
        # scores
        n("ReduceSum", ["point_labels"], ["lsum"], keepdims=0),
        n("Mul", ["lsum", "f01"], ["l1"]),
        n("Add", ["l1", "f03"], ["iou1"]),
        n("ReduceMean", ["image_embeddings"], ["emb_mean"], keepdims=0),
        n("Mul", ["emb_mean", "f0"], ["emb0"]),
        n("Add", ["emb0", "f05"], ["iou2"]),
        n("ReduceSum", ["mask_input"], ["mi"], keepdims=0),
        n("Mul", ["mi", "f0"], ["mi0"]),
        n("Mul", ["has_mask_input", "f0"], ["hm0"]),
        n("Squeeze", ["hm0"], ["hm0s"]),
        n("Add", ["mi0", "f06"], ["iou0a"]),
        n("Add", ["iou0a", "hm0s"], ["iou0"]),
        n("Unsqueeze", ["iou0", "ax0"], ["u0"]),
        n("Unsqueeze", ["iou1", "ax0"], ["u1"]),
        n("Unsqueeze", ["iou2", "ax0"], ["u2"]),
        n("Concat", ["u0", "u1", "u2"], ["iou"], axis=0),
        n("Unsqueeze", ["iou", "ax0"], ["iou_predictions"]),
        n("Identity", ["mask_input"], ["low_res_masks"]),
    ]
    inits = [
        c("c1024", np.array([1024.0], np.float32)),
        c("i0", np.array(0, np.int64)), c("i1", np.array(1, np.int64)),
        c("i0s", np.array(0, np.int64)), c("i1s", np.array(1, np.int64)),
        c("f0", np.array(0.0, np.float32)), c("f1", np.array(1.0, np.float32)),
        c("f4", np.array(4.0, np.float32)), c("half", np.array(0.5, np.float32)),
        c("f01", np.array(0.1, np.float32)), c("f03", np.array(0.3, np.float32)),
        c("f05", np.array(0.5, np.float32)), c("f06", np.array(0.6, np.float32)),
        c("ax0", np.array([0], np.int64)), c("ax1", np.array([1], np.int64)),
    ]
    f = TensorProto.FLOAT
    inputs = [
        helper.make_tensor_value_info("image_embeddings", f, [1, 256, 64, 64]),
        helper.make_tensor_value_info("point_coords", f, [1, "num_points", 2]),
        helper.make_tensor_value_info("point_labels", f, [1, "num_points"]),
        helper.make_tensor_value_info("mask_input", f, [1, 1, 256, 256]),
        helper.make_tensor_value_info("has_mask_input", f, [1]),
        helper.make_tensor_value_info("orig_im_size", f, [2]),
    ]
    outputs = [
        helper.make_tensor_value_info("masks", f, [1, 3, "H", "W"]),
        helper.make_tensor_value_info("iou_predictions", f, [1, 3]),
        helper.make_tensor_value_info("low_res_masks", f, [1, 1, 256, 256]),
    ]
    graph = helper.make_graph(nodes, "sam_decoder_signature", inputs, outputs, inits)
    model = helper.make_model(graph, opset_imports=OPSET, producer_name="grounder-fixtures")
    model.ir_version = 8
    save(model, f"{out_dir}/sam-decoder-signature.onnx")


if __name__ == "__main__":
    out = sys.argv[1] if len(sys.argv) > 1 else "tests/fixtures/vision"
    yolo(out)
    sam_encoder(out)
    sam_decoder(out)
